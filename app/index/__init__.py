"""Everything a search reads from memory: caches of the database, kept current by its change
feed (:mod:`app.db.changes`) and rebuilt from it when missing or stale.

- :mod:`app.index.kinds`: the kinds of FAISS index (flat, IVF) and building one;
- :mod:`app.index.descriptor_index`: one FAISS index, ids = clip ids (a clip index) or window
  ids (a window index of moments search), kept in step with the database; built on
  :mod:`app.index.saved_index` (saving it, reading it back; its files
  :mod:`app.index.index_file`, its batched saves :mod:`app.index.delayed_save`), built on
  :mod:`app.index.held_index` (the FAISS index in memory: what it holds, its searches);
  every descriptor's: :mod:`app.index.index_set`;
- :mod:`app.index.catalogue`: what a search shows of each clip (an overlay of changes, the
  change feed, its file) over :mod:`app.index.catalogue_base` (the file's columns);
- :mod:`app.index.sources`: the database's view of what an index holds, to load and sync it;
- :mod:`app.index.places`: where each window of a window index lies (moments search);
- :mod:`app.index.locks`: reader/writer lock and the index directory's file lock.
"""

# FAISS runs one OpenMP thread a process: app/__init__.py sets OMP_NUM_THREADS before any import.
