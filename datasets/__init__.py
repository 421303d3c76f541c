"""Real file formats -> samples: VOC / SBD / COCO / TUM RGB-D readers, transforms and the
``UDADataModule``. The synthetic generator that writes those formats is :mod:`uss_slam.synthetic`."""
