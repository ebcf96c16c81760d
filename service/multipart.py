"""Streaming ``multipart/form-data`` parser that writes file parts straight into staging.

Starlette's form parser spools every file to the system temp folder, and the submission was
then copied again into staging and hashed in the event loop: twice the disk while in flight,
and a 300 MB upload stalled every other request. Here each file part goes once to its final
staging name and is hashed as it arrives, and the parsing, writing and hashing run in a worker
thread, a block of about a megabyte at a time, so the event loop only moves bytes.
"""

from __future__ import annotations

import hashlib
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from python_multipart.exceptions import MultipartParseError
from python_multipart.multipart import MultipartParser, parse_options_header
from starlette.concurrency import run_in_threadpool

from api_schemas import InvalidParam
from service.core.problems import ProblemError

__all__ = ["FilePart", "FormParts", "parse_multipart"]

#: Bytes gathered from the network before they are handed to the parsing thread.
_BLOCK = 2**20


@dataclass
class FilePart:
    """A file part written to ``path``: the client's file name, size and SHA-256."""

    name: str
    filename: str
    path: Path
    size: int = 0
    sha256: str = ""


@dataclass
class FormParts:
    """What a form held: file parts (on disk) and text fields (in memory), in order."""

    files: list[FilePart] = field(default_factory=list)
    fields: list[tuple[str, str]] = field(default_factory=list)


def _malformed(detail: str, status: int = 400, part: str = "files") -> ProblemError:
    return ProblemError(status, f"malformed multipart body: {detail}",
                        errors=[InvalidParam(message=detail, field=part)])


class _Collector:
    """python-multipart callbacks: headers per part, file data to disk, fields to memory."""

    def __init__(self, place: Callable[[str, int], Path], *, max_files: int, max_fields: int,
                 max_field_bytes: int) -> None:
        self.place, self.max_files, self.max_fields = place, max_files, max_fields
        self.max_field_bytes = max_field_bytes
        self.parts = FormParts()
        self._headers: dict[bytes, bytes] = {}
        self._field, self._value = b"", b""
        self._out: IO[bytes] | None = None
        self._hash: Any = None
        self._text: bytearray | None = None
        self._text_name = ""
        self.finished = False

    def callbacks(self) -> dict[str, Any]:
        return {"on_part_begin": self._begin, "on_header_field": self._header_field,
                "on_header_value": self._header_value, "on_header_end": self._header_end,
                "on_headers_finished": self._headers_done, "on_part_data": self._data,
                "on_part_end": self._end, "on_end": self._done}

    def _done(self) -> None:
        self.finished = True

    def _begin(self) -> None:
        self._headers = {}

    def _header_field(self, data: bytes, start: int, end: int) -> None:
        self._field += data[start:end]

    def _header_value(self, data: bytes, start: int, end: int) -> None:
        self._value += data[start:end]

    def _header_end(self) -> None:
        self._headers[self._field.lower()] = self._value
        self._field, self._value = b"", b""

    def _headers_done(self) -> None:
        disposition, params = parse_options_header(self._headers.get(b"content-disposition"))
        if disposition != b"form-data" or b"name" not in params:
            raise _malformed("a part without Content-Disposition: form-data; name=...")
        name = params[b"name"].decode("utf-8", "replace")
        if b"filename" in params:
            if len(self.parts.files) >= self.max_files:
                raise _malformed(f"Too many files. Maximum number of files is {self.max_files}.",
                                 413)
            filename = params[b"filename"].decode("utf-8", "replace")
            part = FilePart(name, filename, self.place(filename, len(self.parts.files)))
            self.parts.files.append(part)
            self._out, self._hash = part.path.open("wb"), hashlib.sha256()
        else:
            if len(self.parts.fields) >= self.max_fields:
                raise _malformed(f"Too many fields. Maximum number of fields is "
                                 f"{self.max_fields}.", 413, name)
            self._text, self._text_name = bytearray(), name

    def _data(self, data: bytes, start: int, end: int) -> None:
        chunk = data[start:end]
        if self._out is not None:
            self._out.write(chunk)
            self._hash.update(chunk)
            self.parts.files[-1].size += len(chunk)
        elif self._text is not None:
            self._text += chunk
            if len(self._text) > self.max_field_bytes:
                raise _malformed(f"Part exceeded maximum size of {self.max_field_bytes // 1024}"
                                 "KB.", 413, self._text_name)

    def _end(self) -> None:
        if self._out is not None:
            self._out.close()
            self.parts.files[-1].sha256 = self._hash.hexdigest()
            self._out = None
        elif self._text is not None:
            self.parts.fields.append((self._text_name, self._text.decode("utf-8", "replace")))
            self._text = None

    def close(self) -> None:
        """Close a file left open by a body that ended early."""
        if self._out is not None:
            self._out.close()
            self._out = None


def _boundary(content_type: str) -> bytes:
    ctype, params = parse_options_header(content_type)
    if ctype != b"multipart/form-data":
        raise ProblemError(415, "POST /v1/jobs takes multipart/form-data")
    boundary = params.get(b"boundary")
    if not boundary:
        raise _malformed("no boundary in the Content-Type")
    return boundary


async def parse_multipart(content_type: str, body: AsyncIterator[bytes],
                          place: Callable[[str, int], Path], *, max_files: int,
                          max_fields: int = 16, max_field_bytes: int = 2**20) -> FormParts:
    """Parse a multipart body as it streams in; file parts go to ``place(filename, index)``.

    Raises
    ------
    ProblemError
        415 for another content type; 400 for a malformed body; 413 for too many files or
        fields or a text field over ``max_field_bytes``. Files written so far stay where
        ``place`` put them (the caller removes its staging folder).
    """
    collector = _Collector(place, max_files=max_files, max_fields=max_fields,
                           max_field_bytes=max_field_bytes)
    parser = MultipartParser(_boundary(content_type), collector.callbacks())  # type: ignore[arg-type]
    block: list[bytes] = []
    pending = 0
    try:
        async for chunk in body:
            block.append(chunk)
            pending += len(chunk)
            if pending >= _BLOCK:
                await run_in_threadpool(parser.write, b"".join(block))
                block, pending = [], 0
        await run_in_threadpool(parser.write, b"".join(block))
    except MultipartParseError as exc:
        raise _malformed(str(exc)) from None
    finally:
        collector.close()
    if not collector.finished:
        raise _malformed("the body ends before its closing boundary")
    return collector.parts
