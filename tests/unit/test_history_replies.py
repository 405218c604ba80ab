"""The historian's replies (services/core/historian.py): spliced from stored JSON, merged across historians."""
import pytest

from railswitch.schemas import HistoryReply, decode, encode
from railswitch.services.core.historian import merge_replies, reply_payload, switch_in_key
from tests.history_bus import diagnosis, health


def test_a_reply_spliced_from_stored_payloads_is_the_history_reply_of_those_messages():
    diagnoses, healths = [diagnosis("sw1", k) for k in range(3)], [health("sw1", k) for k in range(2)]
    payload = reply_payload("sw1", "host-1", [encode(d) for d in diagnoses],
                            [encode(h) for h in healths], truncated=True)
    assert decode(HistoryReply, payload) == HistoryReply(switch_id="sw1", historian="host-1", truncated=True,
                                                         diagnoses=diagnoses, health=healths)


def test_replies_of_two_historians_merge_oldest_first_each_message_once_the_latest_kept():
    a = HistoryReply(switch_id="sw1", historian="a", diagnoses=[diagnosis("sw1", k) for k in (0, 2, 4)],
                     health=[health("sw1", k) for k in (0, 2)])
    b = HistoryReply(switch_id="sw1", historian="b", diagnoses=[diagnosis("sw1", k) for k in (1, 2, 3)],
                     health=[health("sw1", k) for k in (1, 3)])
    merged = merge_replies([a, b], limit=4)
    assert [d.throw_index for d in merged.diagnoses] == [1, 2, 3, 4]  # 0 left out by the limit, 2 kept once
    assert [h.throw_index for h in merged.health] == [0, 1, 2, 3]
    assert merged.truncated and merged.historian == "a, b"
    assert not merge_replies([a, b], limit=5).truncated


@pytest.mark.parametrize("key, switch_id", [
    ("railswitch/sw1/history", "sw1"),
    ("railswitch/*/history", None),
    ("railswitch/sw*/history", None),
    ("railswitch/**", None),
])
def test_a_concrete_key_names_its_switch_and_a_wildcard_asks_for_every_match(key, switch_id):
    assert switch_in_key(key) == switch_id


def test_a_key_whose_switch_chunk_is_no_switch_id_is_refused():
    with pytest.raises(ValueError, match="must be 1 to 64 letters"):
        switch_in_key("railswitch/" + "x" * 65 + "/history")
