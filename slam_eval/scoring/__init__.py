"""Scoring and reports of a SLAM run, the same for every system: ATE / RPE against ground truth
as evo computes them (:mod:`.metrics`), one scoring function with its ``metrics.json`` keys
(:mod:`.evaluation`), one report writer (``metrics.json``, ``report.md``, plots; and the
comparison table of several filter sets; :mod:`.report`, :mod:`.plots`), the output folder and
its manifest (:mod:`.run_folder`), and the ``uss-traj`` command that scores any TUM trajectory
file (:mod:`.traj_cli`).
"""
