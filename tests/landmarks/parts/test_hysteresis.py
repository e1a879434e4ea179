"""Which bank entry a sequence shows (landmarks.parts.hysteresis): the nearest at first, kept until another is
cheaper by more than ``switch``, cross-faded in over ``fade`` frames, chosen afresh after a gap or a new bank."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.parts.hysteresis import FADE, SWITCH, EntryTrack


def test_the_first_frame_takes_the_cheapest_entry_with_no_fade():
    rng = np.random.default_rng(63)
    for _ in range(20):
        cost = rng.uniform(0.0, 10.0, int(rng.integers(1, 9)))
        track = EntryTrack()
        assert track(cost) == (int(cost.argmin()), None, 0.0)
        assert track.switches == 0
    assert EntryTrack()([4.0]) == (0, None, 0.0)  # a single entry
    assert EntryTrack()(np.array([3, 1, 2], np.int64)) == (1, None, 0.0)  # any real dtype, read as float64
    assert EntryTrack()([2.0, 1.0, 1.0]) == (1, None, 0.0)  # a tie: the first of the cheapest (argmin)


def test_the_defaults_are_the_modules_constants():
    track = EntryTrack()
    assert track.switch == SWITCH and track.fade == FADE
    assert SWITCH > 0 and FADE >= 1


def test_an_entry_cheaper_by_less_than_switch_does_not_take_over():
    track = EntryTrack(switch=1.0, fade=3)
    assert track([0.0, 5.0])[0] == 0
    for cost in ([0.5, 0.0], [2.0, 1.1], [1.0, 0.0]):  # cheaper by 0.5, 0.9, exactly switch: the gap must exceed it
        assert track(cost) == (0, None, 0.0)
    assert track.switches == 0
    assert EntryTrack(switch=1.0)([0.5, 0.0])[0] == 1  # a fresh track has nothing to keep


def test_an_entry_cheaper_by_more_than_switch_takes_over_and_fades_in():
    fade = 3
    track = EntryTrack(switch=1.0, fade=fade)
    assert track([0.0, 5.0, 5.0]) == (0, None, 0.0)
    clear = [3.0, 1.9, 5.0]  # entry 1 cheaper by 1.1
    shown = [track(clear) for _ in range(fade + 3)]
    assert track.switches == 1
    assert all(entry == 1 for entry, _, _ in shown)
    fading = shown[:fade]
    assert all(previous == 0 for _, previous, _ in fading)
    weights = np.array([weight for _, _, weight in fading])
    assert ((weights > 0) & (weights < 1)).all() and (np.diff(weights) < 0).all()
    np.testing.assert_allclose(weights, [3 / 4, 2 / 4, 1 / 4])  # fading / (fade + 1)
    assert shown[fade:] == [(1, None, 0.0)] * 3
    # the new entry is kept in turn: the old one back within switch does not return
    assert track([1.5, 2.0, 5.0]) == (1, None, 0.0)
    # a third entry clearly cheaper: a second switch, fading from the kept entry (1), not the first (0)
    entry, previous, weight = track([9.0, 9.0, 0.0])
    assert (entry, previous, weight) == (2, 1, 0.75) and track.switches == 2


def test_a_switch_during_a_fade_restarts_the_fade_from_the_entry_just_shown():
    track = EntryTrack(switch=1.0, fade=4)
    track([0.0, 9.0, 9.0])
    assert track([9.0, 0.0, 9.0]) == (1, 0, 0.8)
    assert track([9.0, 0.0, 9.0]) == (1, 0, 0.6)
    assert track([9.0, 9.0, 0.0]) == (2, 1, 0.8)
    assert track.switches == 2


def test_a_zero_fade_switches_without_a_cross_fade_and_a_zero_switch_takes_any_cheaper_entry():
    track = EntryTrack(switch=1.0, fade=0)
    track([0.0, 5.0])
    assert track([5.0, 0.0]) == (1, None, 0.0) and track.switches == 1
    eager = EntryTrack(switch=0.0, fade=2)
    eager([1.0, 1.0 + 1e-9])
    assert eager([1.0, 1.0]) == (0, None, 0.0)  # equal is not cheaper
    assert eager([1.0, 1.0 - 1e-9])[0] == 1 and eager.switches == 1


def test_reset_chooses_afresh_with_no_fade_and_keeps_the_switch_count():
    track = EntryTrack(switch=1.0, fade=3)
    track([0.0, 9.0])
    track([9.0, 0.0])  # a switch, fading from 0
    assert track.switches == 1 and track.previous == 0 and track.fading > 0
    track.reset()
    assert track.current is None and track.previous is None and track.fading == 0
    # afresh: the cheapest, though the kept entry would have held against this small gap; not a switch, no fade
    assert track([0.5, 0.0]) == (1, None, 0.0)
    track.reset()
    assert track([0.0, 0.5]) == (0, None, 0.0)
    assert track.switches == 1  # reset clears the choice, not the count


def test_a_shorter_cost_vector_than_the_kept_index_restarts_the_track():
    track = EntryTrack(switch=1.0, fade=3)
    track([9.0, 9.0, 9.0, 9.0, 0.0])
    assert track([9.0, 9.0, 0.0, 9.0, 9.0])[:2] == (2, 4)  # a switch, fading from 4
    track([9.0, 9.0, 0.0, 9.0, 9.0])
    track([0.0, 9.0, 0.0, 9.0, 9.0])
    assert track.current == 2
    # a bank of 2 entries: entry 2 is not in it; its cheapest is shown at once, not counted as a switch, no fade
    assert track([0.5, 0.0]) == (1, None, 0.0)
    assert track.switches == 1 and track.previous is None and track.fading == 0
    # then kept against the new bank's costs as usual
    assert track([0.0, 0.5]) == (1, None, 0.0)
    # a vector that still holds the kept index goes on as before (the track cannot tell two banks apart)
    assert track([0.5, 0.0, 9.0]) == (1, None, 0.0)


def test_an_infinite_cost_is_never_shown_while_a_finite_one_exists():
    assert EntryTrack()([np.inf, 3.0, np.inf]) == (1, None, 0.0)
    track = EntryTrack(switch=1.0, fade=2)
    track([0.0, 2.0])
    # the kept entry becomes unusable: any finite entry is cheaper by more than switch (inf - switch = inf)
    assert track([np.inf, 50.0]) == (1, 0, 2 / 3)
    assert track.switches == 1
    # an unusable entry does not take over from a finite kept one, however large
    assert track([np.inf, 1e300]) == (1, 0, 1 / 3)


def test_all_infinite_costs_show_the_first_entry_on_a_fresh_track_and_keep_the_kept_one():
    # documented behaviour, not a choice the banks make: their callers return None before asking then
    assert EntryTrack()([np.inf, np.inf, np.inf]) == (0, None, 0.0)  # argmin of all inf is the first index
    track = EntryTrack()
    track([5.0, 5.0, 0.0])
    assert track([np.inf, np.inf, np.inf]) == (2, None, 0.0)  # inf < inf - switch is false: nothing switches
    assert track.switches == 0


@pytest.mark.parametrize("cost", [[], np.zeros((0,)), np.zeros((2, 3)), np.zeros((1, 1)), 1.0])
def test_costs_that_are_not_a_non_empty_vector_raise(cost):
    track = EntryTrack()
    with pytest.raises(ValueError, match="non-empty"):
        track(cost)
    assert track.current is None  # nothing was taken


@pytest.mark.parametrize("switch, fade", [(-0.1, 3), (1.0, -1), (-1.0, -1)])
def test_a_negative_switch_or_fade_raises(switch, fade):
    with pytest.raises(ValueError, match=">= 0"):
        EntryTrack(switch=switch, fade=fade)
