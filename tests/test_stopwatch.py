"""The stopwatch automaton of one interruptible task (002 Fig. 3/4.5), scan by scan.

Times are virtual, in µs, with 10 ms scans; the conveyor's window of 002 §4 ([3, 4] normal,
[3, 5] acceptable, 1 t.u. = 1 s) unless a test says otherwise. Each test drives the automaton
with a timeline of observations, so the expected instants come from the timeline, not from
the code under test.
"""

from __future__ import annotations

import pytest

from hmi.engine.stopwatch import FAULTY, Phase, TaskAutomaton, Window

MS = 1_000
S = 1_000_000
PERIOD = 10 * MS
CONVEYOR = Window(3 * S, 4 * S, 5 * S)


class Run:
    """Feeds a TaskAutomaton scan by scan from a timeline.

    `start`/`end` are instants (µs) at which those events are observed; `suspended` is a list
    of [from, to) intervals of a level "task suspended", passed as interrupt/resume events
    (`events=True`) or as the level (`events=False`). Both forms must behave the same.
    """

    def __init__(self, window=CONVEYOR, starts=(0,), ends=(), suspended=(), events=False):
        self.a = TaskAutomaton(window)
        self.starts, self.ends = set(starts), set(ends)
        self.suspended = list(suspended)
        self.events = events
        self.t = -PERIOD
        self.scan = 0
        self.detections = []
        self.locations: dict[int, str] = {}

    def level(self, t: int) -> bool:
        return any(lo <= t < hi for lo, hi in self.suspended)

    def until(self, t_end: int) -> Run:
        while self.t + PERIOD <= t_end:
            self.t += PERIOD
            self.scan += 1
            t = self.t
            if self.events:
                now, before = self.level(t), self.level(t - PERIOD) if t > 0 else False
                suspend, resume = now and not before, before and not now
            else:
                suspend = self.level(t)
                resume = not suspend
            d = self.a.step(t, self.scan, t in self.starts, t in self.ends, suspend, resume)
            if d is not None:
                self.detections.append(d)
            self.locations[t] = self.a.location
        return self


@pytest.mark.parametrize("events", [False, True], ids=["level", "events"])
def test_a_normal_run_ends_in_time_without_fault(events):
    r = Run(ends=[3_500 * MS], events=events).until(6 * S)
    assert r.detections == [] and r.a.completed == 1 and r.a.faults == 0
    assert (r.a.x_us, r.a.y_us) == (3_500 * MS, 3_500 * MS)
    assert r.locations[3_490 * MS] == "executing" and r.locations[3_500 * MS] == "waiting"
    assert r.a.watchdog.last is None


def test_interruptions_stop_y_but_not_x():
    # Two interruptions: 0.5-1.0 s and 2.0-2.3 s; the task ends at 4.0 s.
    r = Run(ends=[4 * S], suspended=[(500 * MS, 1 * S), (2 * S, 2_300 * MS)]).until(5 * S)
    assert r.detections == []
    assert (r.a.x_us, r.a.y_us) == (4 * S, 3_200 * MS)
    assert r.locations[490 * MS] == "executing"
    assert r.locations[500 * MS] == "interrupted" and r.locations[990 * MS] == "interrupted"
    assert r.locations[1 * S] == "executing"
    assert r.a.completed == 1


def test_bookkeeping_of_x_and_y_at_each_scan():
    r = Run(suspended=[(1 * S, 3 * S)], ends=[6 * S]).until(2 * S)
    assert (r.a.x_us, r.a.y_us) == (2 * S, 1 * S)  # y frozen at 1 s since 1 s
    r.until(2_500 * MS)
    assert (r.a.x_us, r.a.y_us) == (2_500 * MS, 1 * S)


def test_the_papers_scenario_fires_at_x_3_y_1():
    # 002 §4: interrupted after 1 t.u. of work for 2 t.u.; (x2 - y2) >= gamma - alpha = 2.
    r = Run(suspended=[(1 * S, 3 * S)], ends=[5_500 * MS]).until(6 * S)
    (d,) = r.detections
    assert (d.rule, d.time_us, d.x_us, d.y_us) == ("cannot_finish", 3 * S, 3 * S, 1 * S)
    assert r.locations[2_990 * MS] == "interrupted" and r.locations[3 * S] == FAULTY
    trip = r.a.watchdog.last
    assert (trip.time_us, trip.x_us) == (5 * S, 5 * S)  # a plain watchdog: 2 t.u. later


def test_earliest_rule_fires_during_a_longer_interruption():
    r = Run(suspended=[(1 * S, 4 * S)]).until(3 * S)
    (d,) = r.detections
    assert (d.time_us, d.x_us, d.y_us) == (3 * S, 3 * S, 1 * S)
    assert r.a.phase is Phase.SUSPENDED and r.a.location == FAULTY


def test_boundary_x_plus_remaining_work_equal_gamma_is_a_fault_one_scan_less_is_not():
    # Interrupted 1.99 s after 1 s of work: the task can still end at x = 4.99 < gamma.
    ok = Run(suspended=[(1 * S, 2_990 * MS)], ends=[4_990 * MS]).until(6 * S)
    assert ok.detections == [] and ok.a.completed == 1
    assert (ok.a.x_us, ok.a.y_us) == (4_990 * MS, 3 * S)
    # 2.00 s: x + (alpha - y) = 3 + 2 = 5 = gamma, and x == gamma is already late (Property 1).
    late = Run(suspended=[(1 * S, 3 * S)], ends=[5 * S]).until(6 * S)
    (d,) = late.detections
    assert (d.rule, d.x_us, d.y_us) == ("cannot_finish", 3 * S, 1 * S)


def test_never_resumed_task_is_detected_at_gamma_minus_alpha_plus_y():
    r = Run(suspended=[(1_200 * MS, 60 * S)]).until(10 * S)
    (d,) = r.detections
    assert (d.time_us, d.x_us, d.y_us) == (3_200 * MS, 3_200 * MS, 1_200 * MS)
    assert r.a.x_us == 10 * S and r.a.y_us == 1_200 * MS  # still tracked while faulty


def test_too_fast_and_the_alpha_boundary():
    fast = Run(ends=[2_990 * MS]).until(4 * S)
    (d,) = fast.detections
    assert (d.rule, d.time_us, d.y_us) == ("too_fast", 2_990 * MS, 2_990 * MS)
    assert Run(ends=[3 * S]).until(4 * S).detections == []  # y == alpha is normal


def test_overrun_is_detected_while_still_working_at_beta():
    # Ending exactly at y == beta is normal ...
    assert Run(ends=[4 * S]).until(5 * S).detections == []
    # ... but still working at y == beta means it will end with y > beta: fault now.
    r = Run(ends=[4_500 * MS]).until(5 * S)
    (d,) = r.detections
    assert (d.rule, d.time_us, d.x_us, d.y_us) == ("overrun", 4 * S, 4 * S, 4 * S)


def test_overrun_at_the_end_when_beta_falls_between_scans():
    w = Window(3 * S, 4_005 * MS, 5 * S)
    r = Run(window=w, ends=[4_010 * MS]).until(5 * S)
    (d,) = r.detections  # at 4.000 s y < beta; the end is seen at 4.010 s with y > beta
    assert (d.rule, d.time_us, d.y_us) == ("overrun", 4_010 * MS, 4_010 * MS)


def test_late_end_when_the_end_comes_exactly_at_gamma():
    # 1.5 s interruption after 1 s: x - y = 1.5 < 2, so no early detection; the pallet
    # arrives at x = 5.0 = gamma, which Property 1 counts as late.
    r = Run(suspended=[(1 * S, 2_500 * MS)], ends=[5 * S]).until(6 * S)
    (d,) = r.detections
    assert (d.rule, d.time_us, d.x_us, d.y_us) == ("late_end", 5 * S, 5 * S, 3_500 * MS)
    assert r.a.watchdog.last.time_us == 5 * S


def test_deadline_when_still_running_at_gamma_after_the_minimum_work():
    # Work 3.2 s (>= alpha), interrupted 1.7 s (x - y = 1.7 < 2), then works on and on.
    r = Run(suspended=[(3_200 * MS, 4_900 * MS)]).until(6 * S)
    (d,) = r.detections
    assert (d.rule, d.time_us, d.x_us, d.y_us) == ("deadline", 5 * S, 5 * S, 3_300 * MS)


def test_a_task_started_while_suspended_begins_interrupted():
    r = Run(suspended=[(0, 500 * MS)], ends=[4 * S]).until(5 * S)
    assert r.locations[0] == "interrupted" and r.locations[500 * MS] == "executing"
    assert (r.a.x_us, r.a.y_us) == (4 * S, 3_500 * MS) and r.detections == []


def test_a_start_while_running_is_ignored_and_an_end_while_waiting_too():
    r = Run(starts=[0, 1 * S], ends=[3_500 * MS, 4 * S]).until(5 * S)
    assert r.a.attempt == 1 and r.a.completed == 1 and r.detections == []
    assert (r.a.x_us, r.a.y_us) == (3_500 * MS, 3_500 * MS)


def test_the_fault_is_latched_until_reset_and_stays_while_the_task_is_hopeless():
    r = Run(suspended=[(1 * S, 3 * S)], ends=[5_500 * MS]).until(4 * S)
    assert r.a.location == FAULTY
    assert r.a.reset() is False  # still running, x - y = 2 s: it cannot end in time
    assert r.a.location == FAULTY
    r.until(5_500 * MS)  # the late pallet arrives
    assert r.a.location == FAULTY and not r.a.running  # latched, not released by itself
    assert r.a.reset() is True
    assert r.a.location == "waiting" and r.a.latched is None


def test_reset_during_a_new_good_attempt_resumes_monitoring_it():
    r = Run(starts=[0, 6 * S], suspended=[(1 * S, 3 * S)], ends=[5_500 * MS, 9_500 * MS])
    r.until(7 * S)
    assert r.a.location == FAULTY and r.a.attempt == 2 and r.a.running
    assert r.a.reset() is True
    assert r.a.location == "executing"
    r.until(10 * S)
    assert r.a.completed == 1 and r.a.faults == 1 and r.a.location == "waiting"


def test_a_second_faulty_attempt_while_latched_keeps_the_first_evidence():
    r = Run(starts=[0, 6 * S], suspended=[(1 * S, 3 * S), (7 * S, 9 * S)],
            ends=[5_500 * MS, 11_500 * MS]).until(12 * S)
    assert r.a.faults == 2 and len(r.detections) == 1
    assert r.a.latched.attempt == 1 and r.a.last_detection.attempt == 2
    assert r.a.last_detection.x_us == 3 * S


def test_the_watchdog_trips_once_per_attempt_and_not_on_time():
    r = Run(starts=[0, 10 * S], suspended=[(1 * S, 3 * S)], ends=[5_500 * MS, 13_500 * MS])
    r.until(15 * S)
    trip = r.a.watchdog.last
    assert trip.attempt == 1 and trip.time_us == 5 * S  # attempt 2 ended at x = 3.5 s


@pytest.mark.parametrize("alpha,beta,gamma", [(3, 4, 4), (4, 3, 5), (-1, 3, 5)])
def test_a_window_needs_alpha_le_beta_lt_gamma(alpha, beta, gamma):
    with pytest.raises(ValueError):
        Window(alpha * S, beta * S, gamma * S)
