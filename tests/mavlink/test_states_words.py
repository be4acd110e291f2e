"""How a start-up or ending error names its vehicles (``states.describe_states``)."""

from __future__ import annotations

from gcs_swarm.mavlink.states import NAMED_AT_MOST, Phase, describe_states, state_words


def test_one_vehicle_is_named_with_its_phase_and_its_own_words() -> None:
    waiting = state_words(Phase.WAITING_ARMABLE, None)
    assert describe_states("not ready after 4 s", [("2", waiting)]) == (
        "not ready after 4 s: vehicle 2 waiting"
    )
    assert state_words(Phase.FAILED, "no answer to ARM") == "failed (no answer to ARM)"
    assert describe_states("end mode not confirmed", []) == "end mode not confirmed"


def test_vehicles_in_one_state_share_a_clause_and_a_long_list_is_counted() -> None:
    why = state_words(Phase.FAILED, "no answer to PARAM_SET WP_YAW_BEHAVIOR after 10 attempts")
    states = [(f"n5:{i}", why) for i in range(1, 251)]
    states.insert(3, ("n5:900", state_words(Phase.TAKING_OFF, None)))
    text = describe_states("could not be readied", states)
    named = ", ".join(f"n5:{i}" for i in range(1, NAMED_AT_MOST + 1))
    assert text == (
        f"could not be readied: 250 vehicles {named} and {250 - NAMED_AT_MOST} more "
        "failed (no answer to PARAM_SET WP_YAW_BEHAVIOR after 10 attempts); "
        "vehicle n5:900 takeoff"
    )
    assert "\n" not in text and len(text) < 200  # one line, whatever the swarm's size
