"""simeval: evaluation of generative robotic simulation pipelines (quality, diversity, generalization).

Library code, callable without Hydra: loaders return plain task records, metrics take arrays.
"""

__version__ = "0.1.0"
