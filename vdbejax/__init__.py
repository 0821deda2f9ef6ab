"""vdbejax: a JAX experiment engine for exploration strategies in tabular RL."""
