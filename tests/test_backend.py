"""The training-step backend (bcfpipe.train.backend) is chosen once per run, and `Layers` keeps the
fixed layers apart from the trained ones (issue 51)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from bcfpipe.config import ModelConfig, PhaseSchedule, Preset, TrainConfig
from bcfpipe.formats.vocabulary import Kernel
from bcfpipe.model.features import FixedLevel, Layers
from bcfpipe.train.backend import FusedBackend, TorchBackend, make_backend
from bcfpipe.formats.vocabulary import FeatureFormat


def _fixed(size: int) -> FixedLevel:
    return FixedLevel(np.zeros(((size // 4) ** 2, 16), np.uint8), torch.zeros((4, size, size)), size)


def test_layers_keep_the_fixed_ones_apart_in_layer_order():
    t0 = [_fixed(8), _fixed(4)]
    trained = [["dropped"], ["a0", "a1"], ["b0"], ["c0"]]
    layers = Layers.of(trained, {0: t0})
    assert list(layers) == [t0, ["a0", "a1"], ["b0"], ["c0"]] and len(layers) == 4
    assert layers.trained_levels() == ["a0", "a1", "b0", "c0"]
    mapped = layers.map(lambda lv, i, k: f"{lv}@{i}.{k}")
    assert mapped.fixed[0] is t0 and list(mapped)[1:] == [["a0@1.0", "a1@1.1"], ["b0@2.0"], ["c0@3.0"]]
    at = layers.lookup(lambda lv: ("fixed", lv.size), lambda lv, i, k: ("trained", lv, i, k))
    assert at(0, 1) == ("fixed", 4) and at(1, 1) == ("trained", "a1", 1, 1)
    trained[2][0] = "b0'"  # a level replaced in its layer's list (the fused step's rehoming) is the one seen
    assert at(2, 0) == ("trained", "b0'", 2, 0)
    assert layers.each(lambda lv: lv.size, lambda lv, i, k: lv) == [[8, 4], ["a0", "a1"], ["b0'"], ["c0"]]


@pytest.mark.parametrize("kernel,expected", [(Kernel.TORCH, TorchBackend), (Kernel.FUSED, FusedBackend),
                                             (Kernel.AUTO, None)])
def test_the_backend_is_the_kernel_the_config_picks_on_the_device(kernel, expected):
    cfg = TrainConfig(model=ModelConfig(features=FeatureFormat.BC6H, resolutions=(16, 8, 8, 4)), kernel=kernel, device="cpu")
    backend = make_backend(cfg, torch.device("cpu"), {}, (0.0,) * 4)
    assert backend.kernel == kernel.on(torch.device("cpu"))
    assert expected is None or type(backend) is expected
    if backend.kernel == Kernel.TORCH:
        assert backend.library() is None and backend.bicubic() is None


@pytest.mark.parametrize("kernel", [Kernel.TORCH, Kernel.FUSED])
def test_a_training_run_asks_which_kernel_once(kernel, monkeypatch):
    """Every phase runs on the backend made where the run starts: the kernel is asked once."""
    from bcfpipe.texset.texture_set import Channel, TextureSet
    from bcfpipe.train.trainer import train

    asked = []
    on = Kernel.on
    monkeypatch.setattr(Kernel, "on", lambda self, device: asked.append(self) or on(self, device))
    rng = np.random.default_rng(0)
    ts = TextureSet(rng.random((32, 32, 3)).astype(np.float32),
                    tuple(Channel("albedo", c, "color", "a.png", i) for i, c in enumerate("rgb")), 32, 32)
    quick = Preset(PhaseSchedule(4, 0.5, 5e-3, 0.99, 0.99), PhaseSchedule(4, 0.1, 5e-3, 0.99, 0.99),
                   PhaseSchedule(2, 0.0, 2e-3, 1.0, 0.99), 256)
    cfg = TrainConfig(model=ModelConfig(features=FeatureFormat.BC6H, resolutions=(16, 8, 8, 4)), preset=quick, seed=1, device="cpu", threads=1,
                      kernel=kernel)
    tm = train(ts, cfg, measure_float=False)
    assert asked == [kernel] and [h[0] for h in tm.history] == ["warmup", "constrained", "finetune"]
