"""A worked example of a method from outside the harness (``docs/methods.md``): a k-nearest-neighbour classifier
of descriptors of the unlabeled flows, trained on runs exported by ``harness export`` (``docs/export.md``) and
registered as the method ``flow_knn``.

``features``: the descriptors (from an observation alone); ``train``: learning from an export
(``python -m flowclf.train DATA --out flowclf/model.npz``); ``method``: the method the harness runs.
"""

__version__ = "0.1.0"
