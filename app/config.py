"""Service configuration: one ``Settings`` object, filled from arguments or ``MOCAP_*`` variables.

Nothing reads the environment at import time: ``create_app(settings)`` and the CLI build a
``Settings`` and pass it down, so tests run side by side on their own temporary data dirs.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

from pydantic import Field, SecretStr, ValidationInfo, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from app.motion.model import ParseLimits

DATABASE_FILE_NAME = "mocap-index.sqlite3"


class Settings(BaseSettings):
    """Every knob of the service; each field can be set as ``MOCAP_<FIELD>`` (upper case)."""

    model_config = SettingsConfigDict(env_prefix="MOCAP_", extra="ignore", frozen=True)

    data_dir: Path = Field(
        default=Path("data"),
        description=(
            "Directory holding the SQLite database, the uploaded files (files/) and the FAISS "
            "indexes (indexes/). Created if missing; relative paths are taken from the "
            "working directory."
        ),
    )
    database_url: str | None = Field(
        default=None,
        description=(
            "SQLAlchemy database URL. Default: the SQLite file "
            f"<data_dir>/{DATABASE_FILE_NAME}. A postgresql:// URL (psycopg 3, the `postgres` "
            "extra) keeps everything, uploaded files included, in PostgreSQL, so any number of "
            "replicas on any machines can share it; the data dir then holds only the indexes."
        ),
    )
    host: str = Field(default="127.0.0.1", description="Address `mocap-index serve` binds to.")
    port: int = Field(default=8000, ge=1, le=65535, description="Port `mocap-index serve` uses.")
    log_level: str = Field(
        default="info", description="Log level of the server (debug, info, warning, error)."
    )
    workers: int = Field(
        default=1,
        ge=1,
        le=64,
        description=(
            "Processes `mocap-index serve` answers requests with, on one port; one per CPU "
            "core gives the most searches per second. Each holds the indexes in memory (the "
            "server's memory times this) and follows the database like a replica (within "
            "MOCAP_INDEX_REFRESH_SECONDS)."
        ),
    )
    max_upload_bytes: int = Field(
        default=256 * 1024 * 1024,
        gt=0,
        description=(
            "Largest request body accepted, in bytes (all uploaded parts together); larger "
            "uploads get 413 before they are read. The default takes a ten-minute 120 fps "
            "take of a 100-joint rig as BVH text (about 190 MB); a describe holds an upload "
            "twice (the file and its text)."
        ),
    )
    max_frames: int = Field(
        default=100_000, gt=0, description="Most frames a clip may have (422 above)."
    )
    max_joints: int = Field(
        default=512, gt=0, description="Most joints, end sites included, a skeleton may have."
    )
    max_depth: int = Field(
        default=128, gt=0, description="Deepest joint nesting a skeleton may have."
    )
    max_k: int = Field(
        default=1000, gt=0, description="Largest number of neighbours a search may ask for."
    )
    max_page_size: int = Field(
        default=500, gt=0, description="Largest `limit` accepted when listing clips."
    )

    # -- access control, CORS and request-time limits (issue 6: hardening) -----------------
    api_key: SecretStr | None = Field(
        default=None,
        description=(
            "Key that changing the library (POST /clips, PATCH, DELETE) requires, sent as "
            "`Authorization: Bearer <key>` or `X-API-Key: <key>`; several keys may be given "
            "separated by commas. Unset: anyone can change the library (logged at start-up)."
        ),
    )
    require_key_for_reads: bool = Field(
        default=False,
        description=(
            "Also require the API key for reading (listing, downloading, searching); "
            "/health and the docs stay open. Needs MOCAP_API_KEY."
        ),
    )
    require_key_for_heavy: bool = Field(
        default=False,
        description=(
            "Also require the API key for every route that parses an upload or does heavy "
            "work: POST /search, GET and POST /search/moments, POST /skeleton, GET /map, "
            "GET /clips/{id}/file with `format`, `start` or `end`, and any other POST, PUT, "
            "PATCH or DELETE that does not change the library. Needs MOCAP_API_KEY."
        ),
    )
    max_heavy_requests_per_client: int = Field(
        default=4,
        ge=1,
        description=(
            "Heavy requests (those MOCAP_REQUIRE_KEY_FOR_HEAVY names) one client address may "
            "have in progress at once without a valid API key; more answer 429 with "
            "Retry-After. Behind a proxy the address is the proxy's unless it is trusted to "
            "pass the client's (uvicorn's FORWARDED_ALLOW_IPS)."
        ),
    )
    allowed_hosts: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description=(
            "Names requests may be addressed to (the Host header) besides localhost, IP "
            "addresses and MOCAP_HOST, comma-separated; `*` for any name. Other names answer "
            "400 `host_not_allowed`: a web page whose name an attacker points at this "
            "server (DNS rebinding) cannot talk to it. Behind a proxy, list the names users "
            "type, and have the proxy pass the Host header on."
        ),
    )
    cors_origins: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description=(
            "Origins a browser may call the API from (comma-separated, or a JSON list; `*` "
            "for any). Empty: CORS is off and no Access-Control-* header is sent."
        ),
    )
    describe_timeout_seconds: float = Field(
        default=60.0,
        gt=0,
        description=(
            "Longest time describing one uploaded clip (parse, kinematics, descriptors) may "
            "take; past it the upload or search answers 503 `describe_timeout` and stores "
            "nothing. It reaches into the parse: the readers look at the clock every few "
            "thousand lines and between bounded chunks of work, so a hostile file stops "
            "there; then it is checked between stages. A ten-minute 120 fps take of an "
            "80-joint rig takes 15-30 s on a busy 2-core machine."
        ),
    )
    moments: bool = Field(
        default=True,
        description=(
            "Moments search (`/search/moments`): every clip stored is also described as "
            "overlapping windows of 1, 2, 4 and 8 s, kept in the database and in memory by "
            "every server process (about 1 GB of each per 100 hours of motion, and about a "
            "minute more import CPU). false: no windows are described or loaded and moments "
            "search answers 409 `moments_off`; whole-clip search is unchanged. Windows stored "
            "before are kept; after turning it back on, `mocap-index reindex` describes the "
            "clips stored without."
        ),
    )
    max_concurrent_describes: int = Field(
        default=0,
        ge=0,
        description=(
            "Uploads one server process reads and describes at once (POST /clips, /search, "
            "/search/moments, /skeleton); others wait up to MOCAP_DESCRIBE_WAIT_SECONDS for a "
            "slot, then get 503 `busy` with Retry-After. 0 = from the machine: one per CPU "
            "core but one (at least one), fewer when half the memory cannot hold that many "
            "uploads at the MOCAP_MAX_FRAME_VALUES and MOCAP_MAX_UPLOAD_BYTES limits "
            "(docs/hardening.md)."
        ),
    )
    describe_wait_seconds: float = Field(
        default=10.0,
        ge=0,
        description=(
            "Longest time an upload waits for a free describe slot (see "
            "MOCAP_MAX_CONCURRENT_DESCRIBES) before it is answered 503 `busy` with "
            "Retry-After; it waits with its body on disk, holding no memory or thread."
        ),
    )
    max_frame_values: int = Field(
        default=64_000_000,
        gt=0,
        description=(
            "Most numbers the frames of one clip may expand to: frames x max(channels, 9 x "
            "joints), joints counting end sites (BVH, ASF/AMC) or the skeleton's nodes only "
            "(FBX/glTF: meshes and props are not read); checked before anything is "
            "allocated (422 above). It bounds the memory one upload can take whatever its "
            "size in bytes: about 21 bytes per value at the peak of a describe, so 1.4 GB at "
            "the default, plus twice the upload's bytes. The default takes a ten-minute take "
            "at 120 fps (72,000 frames) of a rig of up to 98 joints, fingers included."
        ),
    )
    parser_workers: int = Field(
        default=2,
        ge=1,
        le=64,
        description=(
            "Worker processes that read FBX and glTF uploads (started when first needed, "
            "reused; a reader's crash costs its worker, never the server)."
        ),
    )
    parser_timeout_seconds: float = Field(
        default=60.0,
        gt=0,
        description=(
            "Longest time reading one FBX/glTF file may take in its worker; past it the "
            "worker is killed and the upload answers 422 `unreadable_file`."
        ),
    )
    parser_memory_mb: int = Field(
        default=2048,
        ge=64,
        description=(
            "Memory (address space, MB, above an idle worker's) reading one FBX/glTF file "
            "may take; past it the upload answers 422 `unreadable_file`. A ten-minute "
            "120 fps glTF take of a 78-joint rig peaks at about 1.4 GB in its worker."
        ),
    )
    sqlite_synchronous: str = Field(
        default="FULL",
        pattern="^(?i:full|normal)$",
        description=(
            "SQLite commit durability. FULL: every commit is on disk before the service "
            "answers, so an acknowledged upload, change or delete survives a power cut. "
            "NORMAL: commits reach the disk at WAL checkpoints (faster imports, see "
            "bench/README.md), and the last ones can roll back on a power loss or OS crash "
            "(never on a crash of the service alone)."
        ),
    )
    orphan_file_grace_seconds: float = Field(
        default=600.0,
        ge=0,
        description=(
            "At start-up, stored files no clip refers to (left by a crash between writing a "
            "file and committing its clip, or between a delete and its file removal) are "
            "removed once older than this many seconds; the grace spares the files of an "
            "import running in another process that has not committed yet."
        ),
    )

    @field_validator("api_key", mode="before")
    @classmethod
    def _blank_key_is_none(cls, value: object) -> object:
        if isinstance(value, str) and not value.strip(" ,"):
            return None
        return value

    @field_validator("require_key_for_reads")
    @classmethod
    def _reads_need_a_key(cls, value: bool, info: ValidationInfo) -> bool:
        # The message never shows the key (a model validator's error would print every input).
        if value and info.data.get("api_key") is None:
            raise ValueError("MOCAP_REQUIRE_KEY_FOR_READS needs MOCAP_API_KEY to be set")
        return value

    @field_validator("require_key_for_heavy")
    @classmethod
    def _heavy_needs_a_key(cls, value: bool, info: ValidationInfo) -> bool:
        if value and info.data.get("api_key") is None:
            raise ValueError("MOCAP_REQUIRE_KEY_FOR_HEAVY needs MOCAP_API_KEY to be set")
        return value

    @field_validator("cors_origins", "allowed_hosts", mode="before")
    @classmethod
    def _split_list(cls, value: object) -> object:
        if isinstance(value, str):
            text = value.strip()
            if text.startswith("["):
                return json.loads(text)
            return [origin.strip() for origin in text.split(",") if origin.strip()]
        return value

    @property
    def api_keys(self) -> tuple[bytes, ...]:
        """Every accepted API key as UTF-8 bytes (empty: no key configured)."""
        secret = self.api_key
        if secret is None:
            return ()
        # ``model_copy(update=...)`` does not validate: accept a plain string there too
        text = secret.get_secret_value() if isinstance(secret, SecretStr) else str(secret)
        keys = (key.strip() for key in text.split(","))
        return tuple(key.encode() for key in keys if key)

    # -- end of issue 6 settings -----------------------------------------------------------

    # -- bulk import and search at scale (issue 5) -----------------------------------------
    index_type: str = Field(
        default="auto",
        pattern="^(auto|flat|ivf)$",
        description=(
            "FAISS index kind: `flat` (exact scan), `ivf` (IndexIVFFlat: scans the "
            "MOCAP_IVF_NPROBE nearest of its k-means cells; recall@10 measured in "
            "bench/README.md), or `auto`: flat below MOCAP_INDEX_AUTO_THRESHOLD vectors, ivf "
            "from there when an index is built or loaded."
        ),
    )
    window_codes: str = Field(
        # float32 by default: sq8 measured no faster (on the FAISS build the package index
        # ships, which picks its kernels at run time, AVX2 among them:
        # faiss.get_compile_options() is "OPTIMIZE DD AVX2") and, with its exact vectors
        # mapped, no smaller in memory at 100 h; switching converts a large library's window
        # indexes at start (bench/README).
        default="float32",
        pattern="^(sq8|float32)$",
        description=(
            "What the IVF window indexes of moments search hold of each window: `float32` or "
            "`sq8` (8 bits a number, a quarter of the lists' size; the candidates re-ranked by "
            "their exact vectors, kept in a mapped file beside the index). Changing it "
            "rebuilds the window indexes from their vectors at the next start."
        ),
    )
    clip_codes: str = Field(
        # float32 by default: at a million clips sq8's lists scanned no faster (AVX2 wheels,
        # as for the windows above) and the re-ranking added ~50 us a search (bench/README).
        default="float32",
        pattern="^(sq8|float32)$",
        description=(
            "What the IVF clip indexes of `GET /search` (a library from "
            "MOCAP_INDEX_AUTO_THRESHOLD clips) hold of each clip: `float32` or `sq8` (8 bits "
            "a number, a quarter of the lists' size; twice the candidates wanted are ranked "
            "by their exact vectors, kept in a mapped file beside the index, so the distances "
            "answered are exact). Changing it rebuilds the clip indexes from their vectors at "
            "the next start."
        ),
    )
    index_auto_threshold: int = Field(
        default=100_000,
        gt=0,
        description="Vectors from which `auto` builds an IVF index instead of a flat one.",
    )
    ivf_nlist: int = Field(
        default=0,
        ge=0,
        description="Cells of an IVF index; 0 = 4 x sqrt(vectors), set when it is built.",
    )
    ivf_nprobe: int = Field(
        default=0,
        ge=0,
        description=(
            "Cells an IVF search scans (more: higher recall, slower); 0 = the smallest number "
            "reaching recall@10 >= 0.995 against exact search on a sample, measured when the "
            "index is built. A search filtered by label "
            "scans every cell and stays exact."
        ),
    )
    index_refresh_seconds: float = Field(
        default=0.1,
        ge=0,
        description=(
            "How often (at most) a search or /health checks the database for clips stored or "
            "deleted by another process (another replica, `mocap-index import`) and brings "
            "the in-memory indexes up to date; 0 = before every search."
        ),
    )
    change_retention_hours: float = Field(
        default=168.0,
        gt=0,
        description=(
            "How long the change feed (the rows telling every process which clips changed) "
            "keeps its rows; older ones are deleted by the servers. A replica, or an index "
            "file, away longer than this cannot follow the feed and rebuilds its indexes from "
            "the database at its next start or sync."
        ),
    )
    import_workers: int = Field(
        default=0,
        ge=0,
        description="Worker processes of `mocap-index import`; 0 = one per CPU core.",
    )
    # -- end of issue 5 settings -----------------------------------------------------------
    export_workers: int = Field(
        default=1,
        ge=1,
        le=16,
        description=(
            "Worker processes that write FBX files with Blender's exporter (started when the "
            "first FBX is asked for, then kept warm; each holds Blender, ~300 MB)."
        ),
    )
    export_timeout_seconds: float = Field(
        default=120.0,
        gt=0,
        description=(
            "Longest time writing one FBX file may take in its worker; past it the worker is "
            "killed and the download answers 503 `export_failed`."
        ),
    )
    export_memory_mb: int = Field(
        default=2048,
        ge=64,
        description=(
            "Memory (address space, MB, above an idle export worker's) writing one FBX file "
            "may take; past it the download answers 503 `export_failed`."
        ),
    )
    max_export_clips: int = Field(
        default=500,
        ge=1,
        description="Most clips one `POST /exports` ZIP may hold (422 above).",
    )

    @field_validator("data_dir")
    @classmethod
    def _absolute_data_dir(cls, value: Path) -> Path:
        # Absolute once, so the derived SQLite URL does not depend on a later chdir.
        return value.expanduser().resolve()

    @property
    def sqlalchemy_url(self) -> str:
        """The database URL actually used (``database_url`` or the SQLite default)."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{self.data_dir / DATABASE_FILE_NAME}"

    @property
    def files_dir(self) -> Path:
        """Content-addressed uploaded files: ``files/<sha256[:2]>/<sha256>``."""
        return self.data_dir / "files"

    @property
    def index_dir(self) -> Path:
        """Persisted FAISS indexes, one ``<descriptor>.faiss`` (+ ``.json``) per descriptor."""
        return self.data_dir / "indexes"

    @property
    def parse_limits(self) -> ParseLimits:
        """The limits handed to the motion parsers."""
        return ParseLimits(
            max_frames=self.max_frames,
            max_joints=self.max_joints,
            max_depth=self.max_depth,
            max_values=self.max_frame_values,
        )
