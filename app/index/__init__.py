"""Everything a search reads from memory: caches of the database, kept current by its change
feed (:mod:`app.db.changes`) and rebuilt from it when missing or stale.

- :mod:`app.index.kinds`: the kinds of FAISS index (flat, IVF) and building one;
- :mod:`app.index.descriptor_index`: one FAISS index, ids = clip ids (a clip index) or window
  ids (a window index of moments search), with its file;
- :mod:`app.index.sources`: the database's view of what an index holds, to load and sync it;
- :mod:`app.index.places`: where each window of a window index lies (moments search);
- :mod:`app.index.locks`: reader/writer lock and the index directory's file lock.
"""

import os

# FAISS reads OMP_NUM_THREADS once, when its OpenMP runtime loads, and a single query is not
# faster on more threads (STYLE.md): default to one before the import — faiss is imported only
# in this package, whose modules all run this first, so every entry point (serve, uvicorn
# --factory, tests) gets it — but keep a value the operator set.
os.environ.setdefault("OMP_NUM_THREADS", "1")
