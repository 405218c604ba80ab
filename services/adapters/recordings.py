"""The MCAP adapter: writes schema messages to one channel per key expression and reads them back.

docs/contracts.md section 4: schema encoding jsonschema, message encoding json, log_time = t_ns.
"""

import os
import tempfile
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Self

from mcap.exceptions import EndOfFile, InvalidMagic, RecordLengthLimitExceeded
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel
from mcap.records import Message as McapMessage
from mcap.writer import CompressionType, Writer
from railswitch.schemas import (
    CHANNEL_MODELS,
    Message,
    MessageError,
    decode_counted,
    encode,
    json_schema,
    parse_key_expr,
)
from railswitch.services.ports import RecordedMessage

LIBRARY = "railswitch"  # fixed, so equal messages give byte-identical files
_UINT32 = 2**32  # MCAP sequence numbers are uint32


class RecordingPathError(OSError):
    """A recording cannot be created at the requested path; the message is one line."""


def check_writable(path: str | os.PathLike[str]) -> Path:
    """Fail fast, before a long simulation, if no file can be created at path."""
    target = Path(path)
    if target.is_dir():
        raise RecordingPathError(f"cannot write recording {target}: it is a directory")
    if not target.parent.is_dir():
        raise RecordingPathError(
            f"cannot write recording {target}: directory {target.parent} does not exist"
        )
    try:  # a real probe: os.access is wrong for root and read-only mounts
        with tempfile.TemporaryFile(dir=target.parent):
            pass
    except OSError as e:
        raise RecordingPathError(
            f"cannot write recording {target}: directory {target.parent} is not writable"
            f" ({e.strerror})"
        ) from None
    return target


class RecordingWriter:
    """Context manager writing schema messages to an MCAP file, ZSTD-compressed and deterministic.

    With atomic=True the data goes to .<name>.partial beside path and is renamed to path only
    if the with block succeeds, so a failed run leaves no file. With atomic=False the file is
    finished even on error, which suits a live recorder stopped by a signal. Chunks of 32 KiB
    (a few seconds of one switch) bound what damage at the end of a file can cost.
    """

    def __init__(
        self, path: str | os.PathLike[str], *, chunk_size: int = 32_768, atomic: bool = True
    ) -> None:
        self.path = check_writable(path)
        self.message_count = 0
        self._chunk_size = chunk_size
        self._atomic = atomic
        self._file = self.path.with_name(f".{self.path.name}.partial") if atomic else self.path
        self._schema_ids: dict[type[Message], int] = {}
        self._channels: dict[str, tuple[int, type[Message], str]] = {}
        self._counters: Counter[str] = Counter()
        self._finished = False

    def __enter__(self) -> Self:
        try:
            self._stream: IO[bytes] = open(self._file, "wb")
        except OSError as e:
            raise RecordingPathError(f"cannot write recording {self.path}: {e.strerror}") from None
        self._writer = Writer(
            self._stream, chunk_size=self._chunk_size, compression=CompressionType.ZSTD
        )
        self._writer.start(profile="", library=LIBRARY)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._finished:
            return
        self._finished = True
        try:
            if exc_type is None or not self._atomic:
                self._writer.finish()
            self._stream.close()  # flush now: a full disk must not be renamed into place
            if self._atomic and exc_type is None:
                os.replace(self._file, self.path)
        except OSError as error:
            if exc_type is None:  # else the error already on its way says more
                raise RecordingPathError(f"cannot finish recording {self.path}: {error.strerror}") from None
        finally:
            try:
                self._stream.close()
            except OSError:
                pass  # the data that could not be flushed is lost either way; the error is reported above
            if self._atomic:
                self._file.unlink(missing_ok=True)

    def finish(self) -> None:
        """Write the summary and close the file now, for a writer that is not atomic: a recorder finishes its file as
        soon as it stops recording, so what follows (closing its bus session, which can be slow) cannot cost the file.
        Leaving the with block afterwards does nothing more."""
        if self._atomic:
            raise TypeError("an atomic recording is finished by leaving its with block")
        self.__exit__(None, None, None)

    def flush(self) -> None:
        """Close the chunk in progress and hand everything to the operating system: a process
        killed after this loses nothing written before it."""
        self._writer.flush()

    def write(self, key: str, message: Message, log_time_ns: int | None = None, payload: bytes | None = None) -> None:
        """Append message on the channel of key; log time defaults to the message's t_ns. `payload`: the bytes
        message was decoded from, stored as they are, so what a newer publisher added stays in the file."""
        channel_id, model_cls, switch_id = self._channels.get(key) or self._register(key)
        if type(message) is not model_cls:
            raise TypeError(f"{key} carries {model_cls.__name__}, not {type(message).__name__}")
        if getattr(message, "switch_id", switch_id) != switch_id:
            raise ValueError(f"{key} cannot carry a message of switch_id {message.switch_id!r}")
        log_time = log_time_ns if log_time_ns is not None else getattr(message, "t_ns", None)
        if log_time is None:
            raise ValueError(f"{type(message).__name__} has no t_ns; pass log_time_ns")
        sequence = getattr(message, "seq", None)
        if sequence is None:
            sequence = self._counters[key]
            self._counters[key] += 1
        self._writer.add_message(
            channel_id=channel_id,
            log_time=log_time,
            publish_time=log_time,
            data=encode(message) if payload is None else payload,
            sequence=sequence % _UINT32,
        )
        self.message_count += 1

    def _register(self, key: str) -> tuple[int, type[Message], str]:
        """Create the channel of key (and the schema of its model) on first use."""
        switch_id, kind = parse_key_expr(key)
        model_cls = CHANNEL_MODELS[kind]
        if model_cls not in self._schema_ids:
            self._schema_ids[model_cls] = self._writer.register_schema(
                name=model_cls.__name__, encoding="jsonschema", data=json_schema(model_cls).encode()
            )
        channel_id = self._writer.register_channel(
            topic=key, message_encoding="json", schema_id=self._schema_ids[model_cls], metadata={}
        )
        self._channels[key] = (channel_id, model_cls, switch_id)
        return self._channels[key]


class RecordingReader:
    """Iterate a recording's messages in file order; stop quietly at damage and report it.

    After iteration: messages_read counts messages yielded, skipped counts the others by
    reason (unknown topic or a MessageError reason), ignored counts what the yielded ones held that
    this version does not know (`<kind>: <field>`, `<kind>: contract=N`), damage describes where the file broke.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.messages_read = 0
        self.skipped: Counter[str] = Counter()
        self.ignored: Counter[str] = Counter()
        self.damage: str | None = None

    def __iter__(self) -> Iterator[RecordedMessage]:
        self.messages_read, self.skipped, self.ignored, self.damage = 0, Counter(), Counter(), None
        with open(self.path, "rb") as f:
            for channel, record in self._records(f):
                try:
                    switch_id, kind = parse_key_expr(channel.topic)
                except ValueError:
                    self.skipped["unknown topic"] += 1
                    continue
                try:
                    message, unknown, _ = decode_counted(CHANNEL_MODELS[kind], record.data)
                except MessageError as e:
                    self.skipped[str(e)] += 1
                    continue
                self.ignored.update(f"{kind}: {name}" for name in unknown)
                self.messages_read += 1
                yield RecordedMessage(channel.topic, kind, switch_id, message, record.log_time)

    def _records(self, f: IO[bytes]) -> Iterator[tuple[Channel, McapMessage]]:
        """Raw messages: via the summary index when intact, else a linear scan up to the damage."""
        size = os.fstat(f.fileno()).st_size
        yielded = False
        try:
            indexed = make_reader(f, validate_crcs=True)
            for _, channel, record in indexed.iter_messages(log_time_order=False):
                yielded = True
                yield channel, record
            return
        except Exception as e:  # whatever the library raises on a damaged file
            self.damage = _describe_damage(e, f.tell(), size)
            if yielded:
                return
        # The summary at the end is unreadable (as when truncated): salvage by a linear scan.
        f.seek(0)
        scan = NonSeekingReader(f, validate_crcs=True, record_size_limit=size)
        try:
            for _, channel, record in scan.iter_messages(log_time_order=False):
                yield channel, record
        except Exception as e:
            self.damage = _describe_damage(e, f.tell(), size)


def _describe_damage(error: Exception, position: int, size: int) -> str:
    """One line saying where and how a recording is broken."""
    if isinstance(error, InvalidMagic):
        return "not an MCAP file (bad magic bytes)"
    if isinstance(error, (EndOfFile, RecordLengthLimitExceeded)) or position >= size:
        return f"truncated after {size} bytes: the last record is incomplete"
    detail = " ".join(f"{type(error).__name__}: {error}".split())
    return f"corrupt near byte {position} of {size}: {detail}"


@dataclass(frozen=True)
class Recording:
    """Every message a recording holds, with what could not be read."""

    records: list[RecordedMessage]
    damage: str | None
    skipped: Counter[str]
    ignored: Counter[str]  # what a newer writer added, per name

    @property
    def messages(self) -> list[Message]:
        return [record.message for record in self.records]

    def note(self) -> str | None:
        """One line on damage, skipped messages and what was ignored, or None when the file was clean."""
        notes = []
        if self.damage:
            notes.append(f"{self.damage}; recovered {len(self.records)} messages before it")
        if self.skipped:
            notes.append("skipped " + ", ".join(f"{n} ({reason})" for reason, n in self.skipped.items()))
        if self.ignored:
            notes.append("ignored what this version does not know: "
                         + ", ".join(f"{name} ({n} messages)" for name, n in sorted(self.ignored.items())))
        return "; ".join(notes) or None


def load_recording(path: str | os.PathLike[str]) -> Recording:
    """All decoded messages of a recording, read once, with its damage, skip and ignore counts."""
    reader = RecordingReader(path)
    records = list(reader)
    return Recording(records, reader.damage, reader.skipped, reader.ignored)


def recover_recording(source: str | os.PathLike[str], target: str | os.PathLike[str]) -> Recording:
    """Copy every message that can be read from a damaged recording into a complete new one."""
    recording = load_recording(source)
    if recording.records:
        with RecordingWriter(target) as writer:
            for record in recording.records:
                writer.write(record.key, record.message, record.log_time_ns)
    return recording


def read_recording(path: str | os.PathLike[str]) -> Iterator[RecordedMessage]:
    """Messages of a recording; use RecordingReader to learn what was skipped or damaged."""
    return iter(RecordingReader(path))
