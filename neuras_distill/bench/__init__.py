"""``neuras-distill bench RUN_DIR``: error against run time for one run.

* :mod:`.variants`: the bundle variants (atlas side, MLP size and depth, no view input, no VQ, face budget) as
  config changes of the run's own configuration;
* :mod:`.measure`: the points: the field at several step counts, the plain-texture floor and every bundle,
  scored against a denser march of the field and timed, at each resolution;
* :mod:`.front`: the Pareto front (error against milliseconds per frame) and the recommendation for a target
  frame time;
* :mod:`.run`: the whole bench: the run's field rebuilt from its recorded command, the variants distilled from
  its stored stages (teacher renders, mesh, G-buffers: ``pipeline.cache``), ``bench/`` written in one move.
"""

from .run import bench

__all__ = ["bench"]
