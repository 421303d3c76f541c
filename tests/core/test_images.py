"""The one image reader (``uss_slam.core.images``): whole files decode as OpenCV decodes them;
truncated or damaged PNG and JPEG files are one :class:`DataFormatError` naming the file, and
the decoders print nothing; label images hold class ids or 255 only."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from uss_slam.core.errors import DataFormatError
from uss_slam.core.images import (
    image_problem,
    read_colour,
    read_depth,
    read_grey,
    read_labels,
    read_rgb,
)
from uss_slam.core.paths import read_text


def _picture(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), (5, 5), 1.5)


ENCODINGS = {
    "png": (".png", []),
    "jpeg": (".jpg", []),
    "jpeg-progressive": (".jpg", [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]),
    "jpeg-restart-markers": (".jpg", [cv2.IMWRITE_JPEG_RST_INTERVAL, 2]),
}


def _encoded(kind: str) -> bytes:
    ext, params = ENCODINGS[kind]
    ok, data = cv2.imencode(ext, _picture(), params)
    assert ok
    return data.tobytes()


@pytest.mark.parametrize("kind", ENCODINGS)
def test_a_whole_image_decodes_as_opencv_decodes_it(kind: str, tmp_path: Path) -> None:
    path = tmp_path / f"x{ENCODINGS[kind][0]}"
    path.write_bytes(_encoded(kind))
    assert np.array_equal(read_colour(path), cv2.imread(str(path), cv2.IMREAD_COLOR))
    path.write_bytes(_encoded(kind) + b"bytes a camera appended")
    assert image_problem(path.read_bytes()) is None


@pytest.mark.parametrize("kind", ENCODINGS)
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_rgb_decoding_gives_the_colour_pixels_and_grey_in_rgb_order(
    kind: str, channels: int, tmp_path: Path
) -> None:
    """``read_rgb`` (decoded in RGB order) is ``read_colour`` with its channels swapped, and the
    grey of the RGB image is the grey of the BGR one, for grey, colour and RGBA files."""
    picture = _picture(channels)
    picture = {1: picture[..., 0], 3: picture, 4: np.dstack([picture, picture[..., 1]])}[channels]
    if kind != "png" and channels == 4:
        picture = picture[..., :3]  # JPEG has no alpha
    ext, params = ENCODINGS[kind]
    path = tmp_path / f"x{ext}"
    path.write_bytes(cv2.imencode(ext, picture, params)[1].tobytes())
    bgr, rgb = read_colour(path), read_rgb(path)
    assert rgb.shape == bgr.shape and rgb.dtype == np.uint8
    assert np.array_equal(rgb, bgr[..., ::-1])
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    assert np.array_equal(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), grey)


def test_rgb_decoding_refuses_a_depth_image(tmp_path: Path) -> None:
    path = tmp_path / "depth.png"
    cv2.imwrite(str(path), np.full((8, 8), 5000, np.uint16))
    with pytest.raises(DataFormatError, match="16-bit PNG"):
        read_rgb(path)


@pytest.mark.parametrize("kind", ENCODINGS)
@pytest.mark.parametrize("keep", [0.1, 0.5, 0.9, -2])
def test_a_truncated_image_is_one_error_and_the_decoder_prints_nothing(
    kind: str, keep: float, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    data = _encoded(kind)
    path = tmp_path / "frame.png"  # the name says PNG; the bytes decide
    path.write_bytes(data[: int(len(data) * keep)] if keep > 0 else data[:keep])
    with pytest.raises(DataFormatError) as caught:
        read_colour(path)
    assert str(caught.value).startswith(f"{path}: truncated ")
    assert len(str(caught.value).splitlines()) == 1
    assert capfd.readouterr().err == ""  # no "Premature end of JPEG file", no libpng line


def test_a_png_with_a_changed_byte_is_refused_by_its_crc(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    data = bytearray(_encoded("png"))
    data[len(data) // 2] ^= 0x5A
    path = tmp_path / "depth.png"
    path.write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match=r"corrupt PNG: the CRC of its IDAT chunk"):
        read_depth(path)
    assert capfd.readouterr().err == ""


def test_image_data_that_is_no_zlib_stream_is_refused_before_libpng_speaks(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """IDAT bytes rewritten with a matching CRC (the chunks are whole): libpng would print
    ``libpng error: IDAT: incorrect header check`` beside the error line."""
    import zlib

    data = bytearray(_encoded("png"))
    at = data.index(b"IDAT")
    length = int.from_bytes(data[at - 4 : at], "big")
    body = bytes((b * 7 + 3) % 256 for b in data[at + 4 : at + 4 + length])
    data[at + 4 : at + 8 + length] = body + zlib.crc32(b"IDAT" + body).to_bytes(4, "big")
    path = tmp_path / "depth.png"
    path.write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match=r"corrupt PNG: its image data \(IDAT chunk at "):
        read_depth(path)
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize(
    ("data", "says"),
    [(b"", "empty file"), (b"not an image at all", "not a readable image"),
     (b"\xff\xd8\x00\x00", "corrupt JPEG: expected a marker at byte 2")],
)  # fmt: skip
def test_other_bad_bytes_are_one_error(data: bytes, says: str, tmp_path: Path) -> None:
    path = tmp_path / "x.png"
    path.write_bytes(data)
    with pytest.raises(DataFormatError, match=says):
        read_colour(path)


def test_labels_outside_the_class_ids_are_refused(tmp_path: Path) -> None:
    labels = np.zeros((8, 8), np.uint8)
    labels[0, :3] = (1, 255, 3)
    path = tmp_path / "labels.png"
    cv2.imwrite(str(path), labels)
    assert np.array_equal(read_labels(path), labels)
    labels[5, 5], labels[6, 6] = 7, 200
    cv2.imwrite(str(path), labels)
    with pytest.raises(DataFormatError) as caught:
        read_labels(path)
    assert str(caught.value) == (
        f"{path}: label values 7, 200 are not class ids; expected 0..3 (background, person, "
        "chair, monitor) or 255 (ignore)"
    )


def test_a_latin1_byte_in_a_text_file_names_its_line(tmp_path: Path) -> None:
    path = tmp_path / "groundtruth.txt"
    path.write_bytes(b"# comment\n1.0 0 0 0 0 0 0 1\n2.0 caf\xe9\n")
    with pytest.raises(DataFormatError) as caught:
        read_text(path)
    assert str(caught.value) == (
        f"{path}:3: not a text file: byte 0xe9 at column 8 is not UTF-8; expected a text file"
    )


def test_a_16_bit_png_is_no_colour_frame(tmp_path: Path) -> None:
    """A depth image listed as a colour frame: refused, not scaled to 8 bits without a word."""
    import cv2
    import numpy as np

    from uss_slam.core.errors import DataFormatError
    from uss_slam.core.images import read_colour, read_depth, read_grey

    path = tmp_path / "depth.png"
    cv2.imwrite(str(path), np.full((8, 8), 5000, np.uint16))
    for read in (read_colour, read_grey):
        with pytest.raises(
            DataFormatError, match="a 16-bit PNG .a depth image..; expected an 8-bit"
        ):
            read(path)
    assert read_depth(path).dtype == np.uint16


@pytest.mark.parametrize(
    ("name", "ext", "says"),
    [("x.png", ".webp", "its content is a WebP image, not the PNG its name says"),
     ("x.jpg", ".png", "its content is a PNG image, not the JPEG its name says"),
     ("x.JPEG", ".png", "its content is a PNG image, not the JPEG its name says"),
     ("x.png", ".jpg", "its content is a JPEG image, not the PNG its name says"),
     ("x.bmp", ".bmp", "its content is a BMP image, not PNG or JPEG"),
     ("x.tif", ".tiff", "its content is a TIFF image, not PNG or JPEG")],
)  # fmt: skip
def test_content_that_is_not_what_the_name_says_is_refused(
    name: str, ext: str, says: str, tmp_path: Path
) -> None:
    """The format is decided by the magic bytes, and must be the one the extension names:
    OpenCV would decode any of these by content, without a word."""
    ok, data = cv2.imencode(ext, np.full((8, 8, 3), 90, np.uint8))
    path = tmp_path / name
    path.write_bytes(data.tobytes())
    with pytest.raises(DataFormatError) as caught:
        read_colour(path)
    assert str(caught.value) == f"{path}: {says}; expected a colour image (PNG or JPEG)"


def test_a_png_and_a_jpeg_under_their_own_names_or_no_image_name_are_read(tmp_path: Path) -> None:
    for name, ext in (
        ("a.png", ".png"),
        ("b.jpeg", ".jpg"),
        ("c.JPG", ".jpg"),
        ("d.frame", ".png"),
    ):
        ok, data = cv2.imencode(ext, np.full((8, 8, 3), 90, np.uint8))
        (tmp_path / name).write_bytes(data.tobytes())
        assert read_colour(tmp_path / name).shape == (8, 8, 3)


@pytest.mark.parametrize("colours", [256, 16, 4, 2])
def test_a_palette_label_png_is_read_as_its_indices(colours: int, tmp_path: Path) -> None:
    """A label PNG written as a palette image whose indices are the class ids (a labelling
    tool's or VOC's ``SegmentationClass`` output; PIL writes 1, 2, 4 or 8 bits by the palette's
    size): the indices, not the palette's colours (refused as a 3-channel image before)."""
    from PIL import Image

    labels = (np.arange(24 * 32).reshape(24, 32) % min(colours, 4)).astype(np.uint8)
    if colours == 256:
        labels[0, 0] = 255  # the ignore label
    image = Image.fromarray(labels, mode="L").convert("P")
    image.putdata(labels.reshape(-1).tolist())
    image.putpalette(([0, 0, 0, 192, 128, 128, 192, 0, 0, 0, 64, 128] * 64)[: colours * 3])
    path = tmp_path / "labels.png"
    image.save(path)
    assert path.read_bytes()[25] == 3  # a palette PNG
    assert np.array_equal(read_labels(path), labels)


def test_a_jpeg_is_read_as_stored_whatever_its_exif_orientation(tmp_path: Path) -> None:
    """An EXIF orientation tag (6: rotate 90 degrees to display) is not applied by any of the
    colour faces: depth and label images are aligned with the stored pixels."""
    from PIL import Image

    stored = np.random.default_rng(0).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(stored).save(tmp_path / "tagged.jpg", exif=exif, quality=95)
    Image.fromarray(stored).save(tmp_path / "plain.jpg", quality=95)
    for read in (read_colour, read_rgb, read_grey):
        assert np.array_equal(read(tmp_path / "tagged.jpg"), read(tmp_path / "plain.jpg"))
    assert read_grey(tmp_path / "tagged.jpg").shape == (24, 32)
