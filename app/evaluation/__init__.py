"""``mocap-index eval``: how well each descriptor groups clips the way people label them.

Follows the protocol of Miura et al. (2013): leave-one-out 1-nearest-neighbour accuracy
(``A_e``) and Ward's clustering with the BIC-chosen number of clusters scored by the
F-measure (plus the adjusted Rand index), and adds a check that the same capture stored in
different file formats (CMU's ASF/AMC and its BVH conversions) gets the same descriptor.

Modules: :mod:`~app.evaluation.metrics` (pure numbers), :mod:`~app.evaluation.describe`
(clips -> cached descriptor vectors), :mod:`~app.evaluation.runner`
(labels and scores), :mod:`~app.evaluation.report` (table, JSON,
figures) and :mod:`~app.evaluation.cli` (the ``eval`` subcommand).
"""

# Here rather than in ``metrics`` so that the CLI can offer them without importing scikit-learn.
COVARIANCE_TYPES = ("spherical", "diag", "tied", "full")
DEFAULT_COVARIANCE = "spherical"
