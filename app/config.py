"""Service configuration: one ``Settings`` object, filled from arguments or ``MOCAP_*`` variables.

Nothing reads the environment at import time: ``create_app(settings)`` and the CLI build a
``Settings`` and pass it down, so tests run side by side on their own temporary data dirs.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

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
            f"<data_dir>/{DATABASE_FILE_NAME}. A postgresql:// URL runs the same code on "
            "PostgreSQL."
        ),
    )
    host: str = Field(default="127.0.0.1", description="Address `mocap-index serve` binds to.")
    port: int = Field(default=8000, ge=1, le=65535, description="Port `mocap-index serve` uses.")
    log_level: str = Field(
        default="info", description="Log level of the server (debug, info, warning, error)."
    )
    max_upload_bytes: int = Field(
        default=50 * 1024 * 1024,
        gt=0,
        description=(
            "Largest request body accepted, in bytes (all uploaded parts together); larger "
            "uploads get 413 before they are read."
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
            max_frames=self.max_frames, max_joints=self.max_joints, max_depth=self.max_depth
        )
