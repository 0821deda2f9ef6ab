"""What is specific to Cruz et al. (2018): the reproduction of its grid
(:mod:`~vdbejax.paper.reproduce`), its claims scored against a result
(:mod:`~vdbejax.paper.claims`) and the ablation over the spec's open details
(:mod:`~vdbejax.paper.ablation`). Everything else in vdbejax is generic."""

#: The public names: the modules (each imported when first named).
__all__ = ["ablation", "ablation_document", "ablation_variants", "claims", "report", "reproduce"]
