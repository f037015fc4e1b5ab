"""A stand-in for torchvision, for running lerobot 0.4.4's dataset code in the tests (requirements-lerobot.txt says
why the real one cannot load here). lerobot imports torchvision at module level and uses one thing of it on the
paths the tests run: transforms.ToTensor, on image (PNG) features. That is given here with torchvision's documented
behaviour (an H x W x C uint8 image -> a C x H x W float tensor in [0, 1]); any other use raises."""


class _Unusable:
    def __init__(self, name: str) -> None:
        self._name = name

    def __getattr__(self, attr: str):
        raise RuntimeError(f"{self._name}.{attr}: torchvision is a stand-in in simeval's tests (see "
                           "requirements-lerobot.txt)")


class _ToTensor:
    def __call__(self, pic):
        import numpy as np
        import torch

        return torch.from_numpy(np.array(pic, dtype=np.uint8, copy=True)).permute(2, 0, 1).float().div(255)


class _Transforms(_Unusable):
    ToTensor = _ToTensor


transforms = _Transforms("torchvision.transforms")


def __getattr__(name: str):
    raise RuntimeError(f"torchvision.{name}: torchvision is a stand-in in simeval's tests (see "
                       "requirements-lerobot.txt)")
