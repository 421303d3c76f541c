"""``uss-experiments``: the USS-SLAM paper's tables by one command — the experiment grid
(:mod:`.grid`), its jobs as Hydra multirun jobs (:mod:`.jobs`), the tables and plots
(:mod:`.tables`) and the stages that chain them (:mod:`.cli`)."""
