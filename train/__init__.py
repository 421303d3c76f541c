"""The adaptation method (LightningModule), losses, schedules, callbacks and the ``uss-train`` entry."""
