"""Adaptation methods (``train/methods/``, config group ``model/method``), the LightningModule,
losses, schedules, callbacks, config checks and the ``uss-train`` entry."""
