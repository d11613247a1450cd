"""``mocap-index import PATH...``: a folder of clips into the library, in parallel processes.

Pipeline
    :func:`app.discovery.discover` finds the clips (``.bvh`` files, ``.amc`` files paired with
    an ``.asf`` of their folder — an ``.amc`` without one is a failure —, and ``.fbx``,
    ``.glb``, ``.gltf``, ``.vrma``, ``.vrm`` files, whose every animation of at least
    :data:`MIN_ANIMATION_FRAMES` frames that moves a node becomes a clip named ``<file> ·
    <animation>``; a file with none such gives the one an upload reads). Worker processes (one
    per core by default) read, parse and describe the clips, a few per task, and send back
    only the measurements, vectors and stored previews (the figure a page draws, made from
    the body the describer built: ~8 KB a second of motion). The main process meanwhile
    opens the library (imports, migration, indexes) in a thread, then stores the described
    clips in batches through :func:`app.services.ingest.store_many` — the code ``POST
    /clips`` uses: files, then one transaction per batch, then one index update per batch,
    then the batch's previews. Batches are stored one at a time on that same thread while the
    main loop goes on feeding the workers and reading their outcomes (a worker waits once its
    outcomes fill the pipe; bench/README.md has the figures).

Idempotent and resumable
    A clip is identified by its content hash (:func:`app.discovery.content_hash`, the rule
    uploads use). Once the library is open, content already stored is recognised before it is
    described and reported as a duplicate; ``store_many`` settles the rest (and races with
    other writers). Every batch commits atomically, so a run stopped half way (Ctrl-C,
    SIGTERM, SIGKILL) loses at most the batch in flight, and running it again stores what is
    missing and nothing twice. Index files are saved when the run ends; a run that was killed
    leaves them behind the database, and whoever opens the library next adds the missing
    vectors from the database.

Workers
    Workers import only the motion core (numpy, scipy), never SQLAlchemy or FAISS. They are
    forked from the main process before it starts any thread (cheapest start), else started
    from a fork server. A worker that dies (a crash in native code, the out-of-memory killer)
    costs one clip: the clips of its task are retried one by one in a new worker, and the one
    that kills a worker again is reported as failed. Workers exit when the main process goes
    away. FBX/glTF readers run in the workers themselves under MOCAP_PARSER_TIMEOUT_SECONDS
    and MOCAP_PARSER_MEMORY_MB (:class:`~app.services.parser_pool.InlineParser`): a reader
    that crashes or overruns costs its worker, like any crash here.

This package imports neither SQLAlchemy nor FAISS at module level (workers import it too).
"""

from app.importer.label_rules import NOTE_COLUMNS, LabelRules
from app.importer.refusals import REFUSALS_FILE, RefusalMemory
from app.importer.report import Duplicate, Failed, Imported, ImportReport
from app.importer.run import DEFAULT_BATCH_SIZE, default_workers, run_import
from app.importer.workers import MIN_ANIMATION_FRAMES, WorkerPool, describe_animations, read_upload

__all__ = [
    "DEFAULT_BATCH_SIZE",
    "MIN_ANIMATION_FRAMES",
    "NOTE_COLUMNS",
    "REFUSALS_FILE",
    "Duplicate",
    "Failed",
    "ImportReport",
    "Imported",
    "LabelRules",
    "RefusalMemory",
    "WorkerPool",
    "default_workers",
    "describe_animations",
    "read_upload",
    "run_import",
]
