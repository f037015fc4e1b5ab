"""Learned models used by the metrics: the DreamerV3-style world model behind dynamics diversity (paper Sec. 3.4,
Table 4). Importing this package does not import torch; `simeval.models.world_model` does."""
