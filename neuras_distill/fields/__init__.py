"""fields: what every field shares, whatever its format: the Field contract, :func:`~.base.check_field` and
chunked evaluation (:mod:`.base`), and safe reading of torch checkpoints (:mod:`.checkpoint`).

Format readers live in their adapter packages (``adapters/``, installed as ``neuras_distill_adapters``:
``instant_ngp``, ``neus``), synthetic scenes in :mod:`neuras_distill.scenes`, network parts shared by formats
in :mod:`neuras_distill.components`."""
