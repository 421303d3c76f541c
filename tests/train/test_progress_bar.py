"""uss-train's progress bar: whole lines, not one redraw per batch, when stdout is a file or a
log (pytest captures it: not a TTY)."""

from __future__ import annotations

import torch
from lightning.pytorch import LightningModule, Trainer

from uss_slam.train.callbacks import LogProgressBar


class _Tiny(LightningModule):
    def __init__(self) -> None:
        super().__init__()
        self.layer = torch.nn.Linear(2, 1)

    def training_step(self, batch: torch.Tensor, batch_idx: int) -> torch.Tensor:
        return self.layer(batch).sum()

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.SGD(self.parameters(), lr=0.01)


def test_a_log_gets_lines_not_one_redraw_per_batch(capsys) -> None:
    loader = torch.utils.data.DataLoader(torch.randn(300, 2), batch_size=1)
    trainer = Trainer(accelerator="cpu", max_epochs=2, logger=False, enable_checkpointing=False,
                      enable_model_summary=False, callbacks=[LogProgressBar()])  # fmt: skip
    trainer.fit(_Tiny(), train_dataloaders=loader)
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line.startswith("Epoch")]
    assert "\r" not in out
    # 600 batches: the last state (the first line comes before the bar is named "Epoch"), not
    # 600 redraws; a very slow machine adds one line per 30 s
    assert 0 < len(lines) <= 4, lines
    assert "300/300" in lines[-1]
