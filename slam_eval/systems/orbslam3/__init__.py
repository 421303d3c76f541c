"""The real ORB-SLAM3 (RGB-D) as a second SLAM system, ``uss-slam system=orbslam3``: its
``system.*`` config (:mod:`.config`), the settings file it reads (:mod:`.settings`), the blanking
of dynamic pixels in its input (:mod:`.masking`), the fresh process each repeat runs in
(:mod:`.worker`), the repeats and their median (:mod:`.repeats`), its outputs (:mod:`.report`) and
the run that ties them together (:mod:`.system`); plus the ORB vocabulary it needs, with the
``uss-vocab`` command that builds one (:mod:`.vocabulary`, :mod:`.vocab_cli`).
"""
