"""The real ORB-SLAM3 (RGB-D) as a second SLAM system: its settings file, the masking of dynamic
pixels, the subprocess that runs each repeat, the median of repeats (:mod:`.system`), and the
ORB vocabulary it needs, with the ``uss-vocab`` command that builds one (:mod:`.vocabulary`,
:mod:`.vocab_cli`).
"""
