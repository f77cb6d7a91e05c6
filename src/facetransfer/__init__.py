"""facetransfer: Face Transfer with Multilinear Models (Vlasic, Brand, Pfister, Popović, SIGGRAPH 2005).

Modules follow the paper: :mod:`tensor` (§3), :mod:`model` (§4.3), :mod:`datasets` (§4.1),
:mod:`impute` (§4.4), :mod:`correspond` (§4.2), :mod:`track` (§5), :mod:`render`,
:mod:`texture`, :mod:`composite` and :mod:`transfer` (§6).

Where to start from Python (each name is importable from the module before it)::

    facetransfer.default_model.load_default_model   the ARKit model, built once (§4.3)
    facetransfer.model.MultilinearModel             synthesize (Eq. 5), mode_basis (Eq. 9)
    facetransfer.model.load_model                   a model file
    facetransfer.arkit.ARKIT_NAMES                  the 52 blendshape names
    facetransfer.tensor.nmode_svd                   N-mode SVD (Eq. 1-4); hooi: ALS
    facetransfer.impute.impute_tensor               missing cells (§4.4)
    facetransfer.track.obtain.obtain_track          a video's track (cached; §5)
    facetransfer.track.Track                        its fields and file (save, load)
    facetransfer.transfer.recombine                 Fig. 1 / Fig. 7 (also time_map)
    facetransfer.performance_edit.edit_track        Fig. 7E: add or scale an expression
    facetransfer.transfer_plan.plan_transfer        read, track, recombine (TransferSources)
    facetransfer.video_transfer.render_plan         a plan rendered and written
    facetransfer.video_transfer.transfer_video      the whole job (TransferSources.of)
    facetransfer.export.export_track                Live Link Face CSV, glTF, USD, JSON

Library errors subclass :class:`facetransfer.errors.FaceTransferError`, a ``ValueError``.
"""

__version__ = "0.1.0"
