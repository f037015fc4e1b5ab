"""The learned models: the DreamerV3-style world model behind dynamics diversity (`world_model`, its training and
evaluation `world_model_training`) and the Diffusion Policy behind generalization (`diffusion_policy`,
`policy_networks`). Importing this package does not import torch."""
