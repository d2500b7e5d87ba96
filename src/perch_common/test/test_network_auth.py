"""A networked graph's replay guard: a signed command is taken once; the same token again is refused
for as long as `check` would still accept it."""

from __future__ import annotations

from perch_common.network_auth import TOKEN_WINDOW, ReplayGuard, check, sign


def test_a_token_is_taken_once_and_its_replay_is_refused():
    guard = ReplayGuard()
    key = b"k" * 32
    token = sign(key, "stage_cancel", "perch/plan_perches", "ab" * 16, "Ctrl-C", now=1000.0)
    assert check(key, token, "stage_cancel", "perch/plan_perches", "ab" * 16, "Ctrl-C", now=1001.0) == ""
    assert guard.refusal(token, now=5.0) == ""
    assert "used before" in guard.refusal(token, now=6.0)
    # a new token for the same command (a second later) is a new command
    fresh = sign(key, "stage_cancel", "perch/plan_perches", "ab" * 16, "Ctrl-C", now=1001.0)
    assert fresh != token and guard.refusal(fresh, now=6.0) == ""


def test_the_guard_remembers_a_token_while_check_accepts_it_and_forgets_it_after():
    guard = ReplayGuard()
    assert guard.refusal("1000:aa", now=0.0) == ""
    # check() accepts a token from TOKEN_WINDOW before to TOKEN_WINDOW after its stamp: 2 windows
    assert "used before" in guard.refusal("1000:aa", now=2 * TOKEN_WINDOW - 1.0)
    # forgotten afterwards (check() refuses it as too old by then): the guard does not grow for good
    assert guard.refusal("1000:aa", now=2 * TOKEN_WINDOW + 5.0) == ""
