"""Network parts shared by checkpoint formats, re-implemented in plain torch.

This room owns:

* :mod:`.tcnn`: tiny-cuda-nn's multiresolution hash grid, its bias-free MLPs (flat parameter layout) and the
  degree-4 SH encoding, as Instant-NGP (``neuras_distill_adapters.instant_ngp``) and hash-grid NeuS
  (``neuras_distill_adapters.neus``) use them.

A network part that more than one format reader uses goes here; a part only one format uses stays in
that format's adapter package. Importing this package imports nothing (torch loads with the submodules).
"""
