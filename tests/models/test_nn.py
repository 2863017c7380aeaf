"""Visual heads and checkpoints: sizes, shapes, clear errors on bad files."""

from __future__ import annotations

import pytest
import torch

from aed_models.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from aed_models.nn import VisualHeadConfig, build_visual_head, encode_frames
from aed_models.nn.attention import DecoderLayer, KVCache


def count(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def test_resnet18_head_has_the_papers_size():
    head = build_visual_head(VisualHeadConfig(arch="resnet18"))
    assert abs(count(head) - 11.31e6) / 11.31e6 < 0.05  # the paper's SVDDED: 11.31M


@pytest.mark.parametrize("arch", ["small_cnn", "resnet18"])
@pytest.mark.parametrize("size", [(32, 32), (40, 56)])
def test_heads_map_frames_to_features(arch, size):
    head = build_visual_head(VisualHeadConfig(arch=arch, out_dim=24, width=4)).eval()
    frames = torch.rand(3, 4, *size)
    before = frames.clone()
    out = head(frames)
    assert out.shape == (3, 24) and torch.isfinite(out).all()
    assert torch.equal(frames, before)
    assert torch.allclose(head(frames[:1]), out[:1], atol=1e-5)  # eval: frames are independent


def test_head_rejects_bad_frames_and_configs():
    head = build_visual_head(VisualHeadConfig(width=4))
    with pytest.raises(ValueError, match=r"expected \(N, 4, H, W\)"):
        head(torch.rand(2, 3, 32, 32))
    with pytest.raises(ValueError, match="H and W must be >= 32"):
        head(torch.rand(2, 4, 16, 32))
    with pytest.raises(ValueError, match="arch='vit'"):
        VisualHeadConfig(arch="vit")
    with pytest.raises(ValueError, match="dropout=1.5"):
        VisualHeadConfig(dropout=1.5)


def test_encode_frames_skips_padding():
    head = build_visual_head(VisualHeadConfig(out_dim=8, width=4)).eval()
    frames = torch.rand(2, 5, 4, 32, 32)
    mask = torch.tensor([[True] * 5, [True] * 3 + [False] * 2])
    out = encode_frames(head, frames, mask)
    assert (out[1, 3:] == 0).all()
    assert torch.allclose(out[1, :3], head(frames[1, :3]), atol=1e-6)


def test_cached_decoder_equals_the_causal_batch():
    torch.manual_seed(0)
    layer = DecoderLayer(16, 4, 32, 0.1, 1e-5).eval()
    x, memory = torch.randn(1, 70, 16), torch.randn(1, 9, 16)
    kv = layer.cross_attn.project_kv(memory)
    batch = layer(x, kv, None)
    cache = KVCache()
    steps = torch.cat(
        [layer(x[:, t : t + 1], kv, None, cache) for t in range(70)], dim=1
    )  # grows past 64
    assert torch.allclose(batch, steps, atol=1e-5)


def test_checkpoint_round_trip(tmp_path):
    state = {"w": torch.arange(4.0)}
    sha = save_checkpoint(
        tmp_path / "a.pt",
        family="policy",
        name="dct",
        config={"x": [1, 2], "y": {"z": None}},
        state_dict=state,
        extra={"epoch": 3},
    )
    ckpt = load_checkpoint(tmp_path / "a.pt", family="policy", name="dct")
    assert (
        ckpt.sha256 == sha
        and ckpt.config == {"x": [1, 2], "y": {"z": None}}
        and ckpt.extra == {"epoch": 3}
    )
    assert torch.equal(ckpt.state_dict["w"], state["w"])
    assert [p.name for p in tmp_path.iterdir()] == ["a.pt"]  # no temporary file left


def test_checkpoint_errors_name_path_and_problem(tmp_path):
    good = tmp_path / "good.pt"
    save_checkpoint(
        good, family="detector", name="probe", config={}, state_dict={"w": torch.ones(1000)}
    )
    with pytest.raises(CheckpointError, match="missing.pt: no such checkpoint"):
        load_checkpoint(tmp_path / "missing.pt", family="policy")
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[:300])
    with pytest.raises(CheckpointError, match="truncated.pt: unreadable checkpoint"):
        load_checkpoint(truncated, family="detector")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError, match="junk.pt: unreadable"):
        load_checkpoint(junk, family="detector")
    foreign = tmp_path / "foreign.pt"
    torch.save({"model": {"w": torch.ones(2)}}, foreign)
    with pytest.raises(CheckpointError, match="foreign.pt: not an AED checkpoint"):
        load_checkpoint(foreign, family="detector")
    with pytest.raises(
        CheckpointError, match="good.pt: a 'detector' checkpoint, expected a 'policy' one"
    ):
        load_checkpoint(good, family="policy")
    with pytest.raises(
        CheckpointError, match="good.pt: a detector checkpoint of 'probe', expected 'lstm_ed'"
    ):
        load_checkpoint(good, family="detector", name="lstm_ed")
    assert issubclass(CheckpointError, ValueError)


def test_check_sequences_returns_inputs_and_mask_or_names_what_is_wrong():
    from aed_models.nn.batch import check_sequences

    frames, features = torch.zeros(2, 3, 4, 8, 8), torch.zeros(2, 3, 5)
    mask = torch.tensor([[1, 1, 0], [1, 1, 1]])
    inputs, got = check_sequences({"frames": frames, "mask": mask}, "demos")
    assert inputs is frames and got.dtype == torch.bool and torch.equal(got, mask.bool())
    inputs, got = check_sequences({"features": features, "frames": frames}, "rollouts")
    assert inputs is features and got.all() and got.shape == (2, 3)
    inputs, _ = check_sequences({"features": features, "frames": frames}, "r", features=False)
    assert inputs is frames
    with pytest.raises(ValueError, match=r"demos: expected a dict with 'frames' .* or 'features'"):
        check_sequences(None, "demos")
    with pytest.raises(ValueError, match=r"x: expected a dict with 'frames' \(B, L, 4, H, W\), "):
        check_sequences({"features": features}, "x", features=False)
    with pytest.raises(ValueError, match=r"x\['frames'\] of shape \(2, 3, 3, 8, 8\)"):
        check_sequences({"frames": torch.zeros(2, 3, 3, 8, 8)}, "x")
    with pytest.raises(ValueError, match=r"x\['features'\] of shape \(2, 5\)"):
        check_sequences({"features": torch.zeros(2, 5)}, "x")
    with pytest.raises(ValueError, match=r"x\['mask'\] of shape \(2, 2\): expected \(2, 3\)"):
        check_sequences({"frames": frames, "mask": mask[:, :2]}, "x")
    with pytest.raises(ValueError, match="x: every sequence needs at least one frame"):
        check_sequences({"frames": frames, "mask": torch.tensor([[0, 1, 1], [1, 1, 1]])}, "x")
