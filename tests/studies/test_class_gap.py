"""studies/class_gap.py: the EM prior of a calibrated model is the target's, and the probe's
IoU and class fractions on a fake experiment folder are those of its model's known labels."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from shared_helpers import colour_labels
from shared_helpers import colour_segmenter as colour_model

from uss_slam.testing.scripts import load_script

class_gap = load_script(Path(__file__).resolve().parents[2] / "studies" / "class_gap.py")
confusion, em_prior, iou, main = (
    class_gap.confusion,
    class_gap.em_prior,
    class_gap.iou,
    class_gap.main,
)


def test_em_recovers_the_target_prior_of_calibrated_posteriors() -> None:
    # Two 1-D Gaussian classes; the model's posteriors are exact under the source prior.
    rng = np.random.default_rng(0)
    prior_s, prior_t = np.array([0.8, 0.2]), np.array([0.4, 0.6])
    y = rng.random(200_000) < prior_t[1]
    x = rng.normal(np.where(y, 1.5, -1.5), 1.0)
    lik = np.stack([np.exp(-((x + 1.5) ** 2) / 2), np.exp(-((x - 1.5) ** 2) / 2)])
    post = lik * prior_s[:, None]
    post /= post.sum(axis=0)
    assert em_prior(post, prior_s) == pytest.approx(prior_t, abs=0.01)
    # Posteriors that already match the source prior leave it unchanged.
    y_s = rng.random(200_000) < prior_s[1]
    x_s = rng.normal(np.where(y_s, 1.5, -1.5), 1.0)
    lik_s = np.stack([np.exp(-((x_s + 1.5) ** 2) / 2), np.exp(-((x_s - 1.5) ** 2) / 2)])
    post_s = lik_s * prior_s[:, None] / (lik_s * prior_s[:, None]).sum(axis=0)
    assert em_prior(post_s, prior_s) == pytest.approx(prior_s, abs=0.01)


def test_confusion_ignores_void_and_iou_is_per_class() -> None:
    labels = np.array([[0, 1, 1, 255]], np.uint8)
    pred = np.array([[0, 1, 0, 3]], np.uint8)
    m = confusion(labels, pred)
    assert m.sum() == 3 and m[1, 0] == 1 and m[1, 1] == 1
    assert iou(m)[:2] == pytest.approx([0.5, 0.5])


def _sequence(folder: Path, images: list[np.ndarray], labels: list[np.ndarray]) -> None:
    (folder / "rgb").mkdir(parents=True)
    (folder / "labels").mkdir()
    for k, (rgb, lab) in enumerate(zip(images, labels, strict=True)):
        cv2.imwrite(str(folder / "rgb" / f"{k:04d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / "labels" / f"{k:04d}.png"), lab)


def test_probe_on_a_fake_experiment(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "OUT"
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(3)]
    truth = [colour_labels(im) for im in images]
    # Every second pixel's label is wrong on the evaluation frames: a known IoU below 1.
    shuffled = [np.where(np.indices(t.shape).sum(0) % 2 == 0, t, (t + 1) % 4).astype(np.uint8)
                for t in truth]  # fmt: skip
    _sequence(out / "data" / "eval" / "walking_xyz", images, shuffled)
    _sequence(out / "data" / "train" / "target_train" / "walking_xyz", images, truth)
    voc = out / "data" / "train" / "voc" / "VOCdevkit" / "VOC2012" / "SegmentationClass"
    voc.mkdir(parents=True)
    Image.fromarray(np.array([[0, 15], [9, 20]], np.uint8)).save(voc / "a.png")
    for model in ("source_only", "oracle"):
        folder = out / "exports" / f"{model}_s0"
        folder.mkdir(parents=True)
        colour_model(folder / f"{model}_s0.onnx")
    report = tmp_path / "gap.json"
    assert main(["--experiment", str(out), "--models", "source_only,oracle", "--seeds", "0",
                 "--sequences", "walking_xyz", "--stride", "1", "--json", str(report)]) == 0  # fmt: skip
    data = json.loads(report.read_text())
    r = data["results"]["source_only"]["0"]
    expected = iou(sum(confusion(s, t) for s, t in zip(shuffled, truth, strict=True)))
    assert r["iou"]["argmax"] == pytest.approx(expected.tolist())
    frac = np.bincount(np.concatenate([t.ravel() for t in truth]), minlength=4) / (3 * 24 * 32)
    assert r["predicted_fraction"] == pytest.approx(frac.tolist())
    # The target training frames are read at every 10th: here the first only.
    assert r["prior_true"] == pytest.approx(
        (np.bincount(truth[0].ravel(), minlength=4) / (24 * 32)).tolist()
    )
    assert data["source_prior"] == pytest.approx([0.25, 0.25, 0.25, 0.25])
    assert "Share of the source-only → oracle mIoU gap" in capsys.readouterr().out


def test_a_missing_sequence_is_one_error(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        main(["--experiment", str(tmp_path), "--sequences", "walking_xyz"])
