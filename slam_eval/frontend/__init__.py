"""The tracking front end: ORB keypoints spread over the image as ORB-SLAM2's extractor does, with
descriptors and back-projected depth (:mod:`.orb`), read and extracted in a worker process with
``prefetch_mode=process`` (:mod:`.process`). Everything downstream (filters, matching, tracking,
mapping) works on the :class:`~.orb.Features` of a frame.
"""
