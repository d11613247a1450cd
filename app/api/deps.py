"""Dependencies shared by the routers, as ``Annotated`` aliases.

``LibraryDep`` is the opened clip library (database sessions, files, indexes) kept in
``app.state`` by the lifespan; ``ClipDep`` loads the clip named in the path or answers 404, so
routes never repeat that check; ``UploadDep`` reads and checks a multipart upload.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable, Iterable
from typing import Annotated, Literal

from fastapi import Depends, File, Form, Query, Request, UploadFile
from starlette.datastructures import FormData

from app.api.limits import Slots
from app.config import Settings
from app.db.clips import ClipRecord
from app.errors import InvalidInput, UnsupportedMediaType
from app.services import clips as clip_service
from app.services.library import Library
from app.services.uploads import Upload, split_files


def get_library(request: Request) -> Library:
    library: Library = request.app.state.library
    return library


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


LibraryDep = Annotated[Library, Depends(get_library)]
SettingsDep = Annotated[Settings, Depends(get_settings)]


def get_clip(clip_id: int, library: LibraryDep) -> ClipRecord:
    return clip_service.get_clip(library, clip_id)


ClipDep = Annotated[ClipRecord, Depends(get_clip)]


async def _read(part: UploadFile | None) -> tuple[str | None, bytes] | None:
    # The body size limit (BodySizeLimit) already bounds what can be read here.
    return None if part is None else (part.filename, await part.read())


# Form fields of one value. FastAPI keeps the last part of a field declared as one value and
# drops the others without a word; ``file`` and ``labels`` are lists and may repeat.
SINGLE_VALUED_UPLOAD_FIELDS = ("skeleton", "motion", "name", "source", "licence", "animation")


def _shown(part: object) -> str:
    value = getattr(part, "filename", part)
    if isinstance(value, str) and len(value) > 40:
        value = value[:40] + "..."
    return repr(value)


def refuse_repeated(form: FormData, fields: Iterable[str]) -> None:
    """422 naming the first of ``fields`` sent more than once in ``form``."""
    for field in fields:
        parts = form.getlist(field)
        if len(parts) > 1:
            what = "value" if isinstance(parts[0], str) else "file"
            names = ", ".join(_shown(part) for part in parts[:5])
            raise InvalidInput(f"field '{field}': send one {what}, not {len(parts)} ({names})")


def single_valued(*fields: str) -> Callable[[Request], Awaitable[None]]:
    """A dependency refusing a repeated form field among ``fields`` (see
    :func:`refuse_repeated`), for routes that do not read their form with :func:`read_upload`."""

    async def check_form(request: Request) -> None:
        refuse_repeated(await request.form(), fields)

    return check_form


def describe_slots(request: Request) -> Slots:
    """The process's describe slots (made when first needed, from the app's settings)."""
    state = request.app.state
    slots: Slots | None = getattr(state, "describe_slots", None)
    if slots is None:
        slots = state.describe_slots = Slots.for_describes(state.settings)
    return slots


async def read_upload(
    request: Request,
    file: Annotated[
        list[UploadFile] | None,
        File(
            description=(
                "One motion file: BVH (`.bvh`), FBX (`.fbx`, binary or ASCII), glTF 2.0 "
                "(`.glb`, or `.gltf`: repeat the field for the files it refers to, its `.bin` "
                "and textures), VRM animation (`.vrma`) or a VRM model (`.vrm`, a GLB). Or send "
                "`skeleton` + `motion`."
            )
        ),
    ] = None,
    skeleton: Annotated[
        UploadFile | None, File(description="An Acclaim skeleton (`.asf`), with `motion`.")
    ] = None,
    motion: Annotated[
        UploadFile | None, File(description="An Acclaim motion (`.amc`) of that skeleton.")
    ] = None,
    name: Annotated[
        str | None,
        Form(description="Clip name; default: the (motion) file name without extension."),
    ] = None,
    labels: Annotated[
        list[str] | None,
        Form(
            description="Free-form tags: repeat the field and/or separate them with commas. "
            "Trimmed; compared case-insensitively (the first spelling is kept)."
        ),
    ] = None,
    source: Annotated[
        str | None,
        Form(description="Where the clip comes from (a URL, a dataset, a person); optional."),
    ] = None,
    licence: Annotated[
        str | None,
        Form(description="Under which terms it may be used, e.g. `CC BY 4.0`; optional."),
    ] = None,
    animation: Annotated[
        str | None,
        Form(
            description=(
                "FBX/glTF: which animation of the file to read, by name (see the clip's "
                "`animations`); default: the longest that moves a node."
            )
        ),
    ] = None,
) -> AsyncIterator[Upload]:
    """The upload, read into memory once a describe slot is free (its body waits on disk;
    see :mod:`app.api.limits`); the slot is held until the request is answered."""
    content_type = request.headers.get("content-type", "")
    if not content_type.lower().startswith("multipart/form-data"):
        raise UnsupportedMediaType(
            f"send the files as multipart/form-data (got {content_type or 'no content type'!r})"
        )
    form = await request.form()  # parsed already for the fields above: the same object
    refuse_repeated(form, SINGLE_VALUED_UPLOAD_FIELDS)
    async with describe_slots(request).hold():
        files = [(part.filename, await part.read()) for part in file or []]
        main, resources = split_files(files)
        yield Upload.from_files(
            file=main,
            resources=resources,
            skeleton=await _read(skeleton),
            motion=await _read(motion),
            name=name,
            labels=labels,
            source=source,
            licence=licence,
            animation=animation,
        )


UploadDep = Annotated[Upload, Depends(read_upload)]


# Ids are 64-bit database keys: a larger one is a bad parameter (422), never a driver error.
ClipIdQuery = Annotated[
    int,
    Query(description="Id of the query clip.", examples=[7], ge=1, le=clip_service.MAX_ID),
]

DescriptorQuery = Annotated[
    str | None,
    Query(
        description="Descriptor to compare with (see GET /descriptors); default: the one "
        "GET /descriptors names as `default` (`motion`).",
        examples=["motion"],
    ),
]


def descriptor_param(
    library: LibraryDep,
    descriptor: DescriptorQuery = None,
) -> str:
    name = library.default_descriptor if descriptor is None else descriptor
    library.descriptor(name)  # 422 naming the known descriptors
    return name


DescriptorDep = Annotated[str, Depends(descriptor_param)]

KQuery = Annotated[
    int,
    Query(description="How many neighbours, 1 to MOCAP_MAX_K (default 1000).", examples=[10]),
]
LABEL_FILTER_DOC = (
    "Only clips carrying this label. Repeat `label` or separate labels with commas "
    "(`label=walk&label=happy` = `label=walk,happy`) for clips carrying all of them; labels "
    "are compared case-insensitively; an empty value is no filter."
)
LabelQuery = Annotated[
    list[str] | None, Query(description=LABEL_FILTER_DOC, examples=[["walk", "happy"]])
]
CollapseQuery = Annotated[
    Literal["capture"] | None,
    Query(
        description="`capture`: one result per group of near-identical clips (one capture "
        "stored as several files or formats: distance under every descriptor below the "
        "thresholds the README gives), the nearest standing for the others, listed in its "
        "`others`."
    ),
]
LICENCE_FILTER_DOC = (
    "Only clips of these licences: repeat `licence` or separate with commas for any of them "
    "(`licence=CC0,CC BY 4.0`); a leading `!` leaves a licence out instead "
    "(`licence=!CC BY-NC 4.0`: every clip but those, clips without a licence included). "
    "Compared with the whole licence, case-insensitively; an empty value is no filter."
)
LicenceQuery = Annotated[
    list[str] | None, Query(description=LICENCE_FILTER_DOC, examples=[["!CC BY-NC 4.0"]])
]
