"""core.png_inflate: PNGs rewritten with their image data stored decode to the same pixels."""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
pytest.importorskip("isal")

from uss_slam.core import png_inflate  # noqa: E402
from uss_slam.core.images import png_problem, read_image  # noqa: E402


def _png(image: np.ndarray, **params: int) -> bytes:
    flags = [v for kv in params.items() for v in (getattr(cv2, kv[0]), kv[1])]
    ok, encoded = cv2.imencode(".png", image, flags)
    assert ok
    return encoded.tobytes()


def _noise(shape: tuple[int, ...], dtype: type, seed: int = 0) -> np.ndarray:
    high = np.iinfo(dtype).max
    return np.random.default_rng(seed).integers(0, high, shape, endpoint=True).astype(dtype)


@pytest.mark.parametrize(
    "image",
    [
        _noise((97, 131, 3), np.uint8),  # colour; rows of 393 bytes: several stored blocks
        _noise((64, 50), np.uint16),  # a depth image
        _noise((40, 33, 4), np.uint8),  # RGBA
        _noise((41, 29, 2), np.uint8)[..., :1].repeat(3, axis=2),  # grey saved as colour
        _noise((300, 300, 3), np.uint8),  # 270 kB of rows: five 64 kB stored blocks
    ],
    ids=["colour", "depth16", "rgba", "grey-as-colour", "several-blocks"],
)
def test_same_pixels_as_libpng_alone(image: np.ndarray) -> None:
    data = _png(image, IMWRITE_PNG_COMPRESSION=9)
    rewritten = png_inflate.stored(data)
    assert rewritten != data  # stored, not passed through
    assert png_problem(rewritten) is None  # a valid PNG: chunk CRCs, IEND
    for flags in (cv2.IMREAD_UNCHANGED, cv2.IMREAD_COLOR, cv2.IMREAD_GRAYSCALE):
        want = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
        got = cv2.imdecode(np.frombuffer(rewritten, np.uint8), flags)
        assert got.dtype == want.dtype and np.array_equal(got, want)


def test_several_idat_chunks_and_reader(tmp_path) -> None:
    """An encoder's many small IDAT chunks become one; ``read_image`` gives libpng's pixels."""
    image = _noise((120, 160, 3), np.uint8, seed=1)
    data = _png(image)
    assert data.count(b"IDAT") > 1
    path = tmp_path / "frame.png"
    path.write_bytes(data)
    assert png_inflate.stored(data).count(b"IDAT") == 1
    assert np.array_equal(read_image(path, cv2.IMREAD_COLOR), image)


def test_left_alone() -> None:
    """Highly compressible data (labels), damaged data and interlaced files pass unchanged."""
    labels = np.zeros((48, 64), np.uint8)
    labels[10:20, 5:30] = 3
    data = _png(labels)
    assert png_inflate.stored(data) is data
    noisy = _png(_noise((32, 32, 3), np.uint8))
    start = noisy.index(b"IDAT") + 4
    damaged = noisy[: start + 20] + bytes(8) + noisy[start + 28 :]  # its CRC is left wrong too
    assert png_inflate.stored(damaged) is damaged
    interlaced = bytearray(noisy)
    interlaced[28] = 1  # Adam7 per its header (CRC aside: only the layout is looked at)
    assert png_inflate.stored(bytes(interlaced)) == bytes(interlaced)
    huge = bytearray(noisy)
    huge[16:24] = (60000).to_bytes(4, "big") * 2  # a header's claim is never allocated
    assert png_inflate.stored(bytes(huge)) == bytes(huge)
