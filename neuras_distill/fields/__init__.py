"""fields: the Field contract (:mod:`.base`), checkpoint helpers (:mod:`.checkpoint`), and for now the
Instant-NGP and NeuS readers. Synthetic scenes live in :mod:`neuras_distill.scenes`, network parts shared by
formats in :mod:`neuras_distill.components`."""
