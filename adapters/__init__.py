"""Field adapters shipped with neuras-distill (installed as ``neuras_distill_adapters``).

Each adapter is registered in the ``neuras_distill.adapters`` entry-point group, exactly as a third-party
adapter would be, and found through ``neuras_distill.registry``.
"""
