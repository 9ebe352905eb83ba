"""What a mistyped config says: the nearest names, briefly, and a subsection's own fields."""

from __future__ import annotations

import pytest

import mmdopt


def test_a_mistyped_field_suggests_the_right_name_briefly():
    with pytest.raises(ValueError) as e:
        mmdopt.MMDOptConfig().replace(n_sample=10)
    msg = str(e.value)
    assert "did you mean 'n_samples'" in msg and len(msg) < 300


def test_a_bad_key_of_a_subsection_lists_its_fields():
    with pytest.raises(ValueError, match="ReducedSetConfig has no field 'bogus_key'.*iterations"):
        mmdopt.MMDOptConfig().replace(reduced_set={"bogus_key": 0.1})
    cfg = mmdopt.MMDOptConfig().replace(reduced_set={"iterations": 5})
    assert cfg.selection.reduced_set.iterations == 5


def test_the_schedule_section_checks_its_fields():
    cfg = mmdopt.MMDOptConfig().replace(margin_ladder=[4, 16], tail_passes=1)
    assert cfg.schedule.margin_ladder == (4.0, 16.0) and cfg.schedule.tail_passes == 1
    assert cfg.program() == mmdopt.MMDOptConfig().program()  # host-side: nothing recompiles
    with pytest.raises(ValueError, match="margin_ladder"):
        mmdopt.MMDOptConfig().replace(margin_ladder=(0.0,))
    with pytest.raises(ValueError, match="level_cap"):
        mmdopt.MMDOptConfig().replace(level_cap=0.7)
    back = mmdopt.MMDOptConfig.from_dict(cfg.to_dict())
    assert back.schedule == cfg.schedule
