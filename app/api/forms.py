"""Reading a multipart body strictly: a malformed one is refused saying what is wrong with it.

Starlette's parser (``request.form()``) is lenient where an upload must not be: a text value or
a file name that is not valid UTF-8 is decoded as Latin-1 (``\\xff\\xfe`` stored as "ÿþ"), a
body cut before its closing boundary is read as if it had fewer parts (the upload then seems
missing), and a part header over python-multipart's size limit (a 100 kB file name) is
"Invalid multipart data." naming nothing. :func:`read_form` parses the body with
:class:`StrictMultiPartParser` instead, before the route's parameters are read
(:class:`app.api.query_check.CheckedQueryRoute` calls it for the routes that take a form), and
leaves the result where ``request.form()`` finds it, so FastAPI and the dependencies read the
same form. What it refuses:

* a text value, field name or file name that is not valid in the body's charset (UTF-8 unless
  the ``Content-Type`` names another): 422 ``invalid_input`` naming the field. File names are
  held to the same rule as text values: they are stored and shown as text, and every browser
  and ``curl`` send them as UTF-8 (RFC 7578, section 4.2);
* a non-empty body without its closing boundary (``--boundary--``): 400 ``bad_request``, the
  body was truncated (an empty body stays "no upload", 422, as before);
* a part header over the size limit: 400 naming the part and its field when they can be read;
  any other malformed body: 400 with python-multipart's or Starlette's own reason.
"""

from __future__ import annotations

import re
from collections.abc import AsyncGenerator
from contextlib import aclosing

from python_multipart.exceptions import MultipartParseError
from python_multipart.multipart import DEFAULT_MAX_HEADER_SIZE, parse_options_header
from starlette.datastructures import FormData
from starlette.formparsers import MultiPartException, MultiPartParser
from starlette.requests import Request

from app.errors import InvalidInput, MalformedRequest

_NAME = re.compile(rb'[;\s]name="([^"\r\n]{0,200})"', re.IGNORECASE)


def is_multipart(request: Request) -> bool:
    content_type, _ = parse_options_header(request.headers.get("content-type"))
    return content_type == b"multipart/form-data"


def _utf8_error(field: str, what: str, data: bytes, charset: str, error: UnicodeError) -> str:
    start = getattr(error, "start", 0)
    shown = data[max(0, start - 8) : start + 8]
    return (
        f"field '{field}': {what} is not valid {charset} (byte {start}, near {shown!r}); "
        "send text as UTF-8"
    )


class StrictMultiPartParser(MultiPartParser):
    """Starlette's parser, refusing what it would decode as Latin-1 or read half of."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.ended = False  # the closing boundary was read
        self.parts = 0
        self.fed = 0
        self.last_chunk = b""

    def _decode(self, data: bytes, field: str, what: str) -> None:
        try:
            data.decode(self._charset)
        except UnicodeDecodeError as error:
            raise InvalidInput(_utf8_error(field, what, data, self._charset, error)) from None

    def on_part_begin(self) -> None:
        self.parts += 1
        super().on_part_begin()

    def on_headers_finished(self) -> None:
        _, options = parse_options_header(self._current_part.content_disposition)
        raw_name = options.get(b"name")
        if raw_name is not None:
            self._decode(raw_name, f"#{self.parts}", "the field name")
            field = raw_name.decode(self._charset)
            if b"filename" in options:
                self._decode(options[b"filename"], field, "the file name")
        super().on_headers_finished()

    def on_part_end(self) -> None:
        if self._current_part.file is None:
            data = bytes(self._current_part.data)
            self._decode(data, self._current_part.field_name, "the value")
        super().on_part_end()

    def on_end(self) -> None:
        self.ended = True
        super().on_end()

    def _field_near(self, offset: int) -> str:
        """The field named in the header line over the limit (python-multipart gives the
        offset in the last chunk where it started counting that line), when it is there."""
        start = self.last_chunk.rfind(b"\n", 0, offset) + 1
        window = self.last_chunk[start : offset + DEFAULT_MAX_HEADER_SIZE]
        found = _NAME.search(window) or _NAME.search(self._current_partial_header_value)
        return f" (field '{found.group(1).decode(self._charset, 'replace')}')" if found else ""

    async def parse(self) -> FormData:
        stream = self.stream

        async def counted() -> AsyncGenerator[bytes, None]:
            async for chunk in stream:
                self.fed += len(chunk)
                self.last_chunk = chunk
                yield chunk

        self.stream = counted()
        try:
            form = await super().parse()
        except MultiPartException as exc:
            cause = exc.__cause__
            if isinstance(cause, MultipartParseError) and "header size" in str(cause):
                raise MalformedRequest(
                    f"multipart body: the header of part {self.parts}"
                    f"{self._field_near(cause.offset)} is longer than {DEFAULT_MAX_HEADER_SIZE} "
                    "bytes (a file or field name that long is refused)"
                ) from None
            reason = str(cause) if cause is not None else exc.message
            raise MalformedRequest(f"multipart body: {reason}") from None
        if self.fed and not self.ended:
            await form.close()
            where = f"in part {self.parts}" if self.parts else "before its first part"
            raise MalformedRequest(
                f"multipart body: truncated: it ends after {self.fed} bytes, {where}, "
                "without its closing boundary ('--<boundary>--')"
            )
        return form


async def read_form(request: Request) -> None:
    """Parse ``request``'s multipart body strictly (see the module docstring) and keep it
    where ``request.form()`` returns it from. Starlette's default limits (1000 files, 1000
    fields, 1 MiB a text value) apply, as they did when FastAPI parsed the body."""
    if request._form is not None:  # parsed already
        return
    async with aclosing(request.stream()) as stream:
        parser = StrictMultiPartParser(request.headers, stream)
        request._form = await parser.parse()  # Request.form() returns it
