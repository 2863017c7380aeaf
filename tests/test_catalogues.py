"""Catalogues: sizes of the paper's table, determinism, and base/novel disjointness."""

from __future__ import annotations

import pytest

import aed_tasks

from .conftest import ALL_TASKS

PAPER_SIZES = {
    "CloseDrawer": (18, 18), "PressButton": (27, 18), "PickPlace": (90, 42), "MoveGlassCup": (42, 20),
    "OrganizeTable": (49, 25), "BackToBox": (60, 18), "FactoryPacking": (36, 12),
}  # fmt: skip


@pytest.mark.parametrize("task", ALL_TASKS)
def test_catalogue_sizes_match_the_paper(task):
    cls = aed_tasks.get_task(task)
    assert (len(cls.get_catalogue("base")), len(cls.get_catalogue("novel"))) == PAPER_SIZES[task]


@pytest.mark.parametrize("task", ALL_TASKS)
def test_base_and_novel_share_no_texture_colour_or_shape(task):
    cls = aed_tasks.get_task(task)
    pools = {}
    for split in ("base", "novel"):
        envs = cls.get_catalogue(split)
        pools[split] = (
            set().union(*(e.textures() for e in envs)),
            set().union(*(e.colours() for e in envs)),
            set().union(*(e.shapes() for e in envs)),
        )
        assert all(e.split == split for e in envs)
    for name, base, novel in zip(("textures", "colours", "shapes"), pools["base"], pools["novel"], strict=True):
        assert base, f"{task} base environments have no {name}"
        assert not base & novel, f"{task} base and novel share {name}: {sorted(map(str, base & novel))[:5]}"


@pytest.mark.parametrize("task", ALL_TASKS)
def test_environments_are_distinct_and_deterministic(task):
    cls = aed_tasks.get_task(task)
    for split in ("base", "novel"):
        envs = cls.get_catalogue(split)
        assert len(set(map(repr, envs))) == len(envs), f"{task} {split} repeats an environment"
        assert cls.make_environment(split, 0) == envs[0]
