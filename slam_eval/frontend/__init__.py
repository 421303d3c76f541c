"""The tracking front end: ORB keypoints spread over the image as ORB-SLAM2's extractor does, with
descriptors and back-projected depth (:mod:`.orb`), and descriptor matching, brute force and
guided by projection (:mod:`.matching`). Everything downstream (filters, tracking, mapping) works
on the :class:`~.orb.Features` of a frame.
"""
