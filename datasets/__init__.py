"""File formats and samples: VOC / SBD / COCO / TUM RGB-D, class maps, transforms, the data
module, and the synthetic world.

Importing this package is cheap and torch-free (the SLAM runtime uses :mod:`.tum_io`,
:mod:`.classes` and :mod:`.errors`); torch-based modules are imported from their own files.
"""
