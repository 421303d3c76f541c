"""The adaptation method (LightningModule), losses, schedules, Hydra entry points, ONNX export."""
