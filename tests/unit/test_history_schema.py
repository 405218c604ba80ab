"""History queries (schemas/history.py): times, limits and kinds as a Zenoh selector's parameters carry them."""
import pytest

from railswitch.schemas import MAX_LIMIT, HistoryQuery, parse_time
from railswitch.schemas.history import format_time


def test_a_time_is_iso_8601_in_utc_unless_it_names_an_offset_or_integer_nanoseconds():
    assert parse_time("2024-05-01T12:00:00Z") == 1_714_564_800 * 10**9
    assert parse_time("2024-05-01T14:00:00+02:00") == 1_714_564_800 * 10**9
    assert parse_time("2024-05-01T12:00:00") == 1_714_564_800 * 10**9  # no offset: UTC
    assert parse_time("2024-05-01") == 1_714_521_600 * 10**9
    assert parse_time("1714564800000000001") == 1_714_564_800_000_000_001
    assert format_time(1_714_564_800_123_456_789) == "2024-05-01T12:00:00.123Z"


@pytest.mark.parametrize("text, words", [
    ("yesterday", "neither ISO-8601"),
    ("2024-13-01", "neither ISO-8601"),
    ("-1", "outside the accepted range 1970-01-01"),
    ("9999-01-01", "outside the accepted range"),  # beyond 64-bit nanoseconds
])
def test_a_bad_time_names_itself_and_what_is_accepted(text, words):
    with pytest.raises(ValueError, match=words):
        parse_time(text, "since")


def test_parameters_become_a_query_and_back():
    query = HistoryQuery.from_parameters({"since": "2024-05-01", "until": "1714564800000000000", "limit": "5",
                                          "kind": "health"})
    assert (query.since_ns, query.until_ns, query.limit, query.kind) == (
        1_714_521_600 * 10**9, 1_714_564_800 * 10**9, 5, "health")
    assert HistoryQuery.from_parameters(dict(p.split("=") for p in query.parameters().split(";"))) == query
    assert HistoryQuery.from_parameters({}).kinds() == ("diagnosis", "health", "alarm")


@pytest.mark.parametrize("parameters, words", [
    ({"limit": "0"}, f"limit 0 is outside the accepted range 1 … {MAX_LIMIT}"),
    ({"limit": str(MAX_LIMIT + 1)}, "outside the accepted range"),
    ({"limit": "many"}, "limit 'many' is not an integer"),
    ({"kind": "motor"}, "kind 'motor' is not one of diagnosis, health"),
    ({"limt": "5"}, "unknown query parameter 'limt'; accepted: since, until, limit, kind"),
    ({"since": "2024-02-01", "until": "2024-01-01"}, "is not before until"),
])
def test_a_bad_query_is_refused_in_one_line_naming_the_problem(parameters, words):
    with pytest.raises(ValueError) as error:
        HistoryQuery.from_parameters(parameters)
    assert words in str(error.value) and "\n" not in str(error.value)
