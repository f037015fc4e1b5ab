"""What runs the models: the one training loop (`trainer`), checkpoints, devices, preemption on a cluster and CUDA
graph capture."""
