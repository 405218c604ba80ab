"""The notifier's wait between failed attempts (services/core/notifier.py): doubling, capped, jittered."""
from railswitch.services.core.notifier import backoff_s


def test_the_wait_doubles_from_half_a_second_up_to_30_s_each_drawn_between_half_and_all_of_it():
    for failures, full_s in [(1, 0.5), (2, 1.0), (3, 2.0), (7, 30.0), (40, 30.0), (100_000, 30.0)]:
        waits = [backoff_s(failures, 0.5, 30.0) for _ in range(200)]
        assert full_s / 2 <= min(waits) and max(waits) <= full_s
        assert max(waits) - min(waits) > full_s / 4  # jittered: notifiers failing together spread out
