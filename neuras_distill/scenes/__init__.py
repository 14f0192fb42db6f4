"""Synthetic scenes: fields built in code, not read from a checkpoint (tests, demos, stability probes).

This room owns:

* :mod:`.synthetic`: the ``SCENES`` registry and :func:`~.synthetic.make_scene` (``"bunny"``,
  ``"bunny-matte"``, ``"sphere"``, ``"torus"``, ``"street"``, ``"gradient-ball"``), and the Stanford-bunny field;
* :mod:`.analytic`: analytic SDFs with exact surfaces (sphere, torus, box), VolSDF's Laplace density and the
  SDF -> density wrapper;
* :mod:`.street`: the embedded street scene (metres, a driving trajectory);
* :mod:`.gradient_ball`: the soft-fringed density ball with its own helix of cameras.

Every scene is a field of the contract in :mod:`neuras_distill.fields.base`. A new synthetic scene goes here,
registered in ``synthetic.SCENES``. Importing this package imports nothing (torch loads with the submodules).
"""
