"""What a transfer makes of its render's set-up on a thread while the target is tracked
(:func:`facetransfer.transfer_plan._setup_ahead`): the regions' model parts, as the regions
would make them."""

import numpy as np

from facetransfer import transfer_plan as tp
from facetransfer.rewrite_options import RewriteOptions


def test_the_model_parts_made_ahead_are_the_regions_own(arkit_model):
    """What :func:`facetransfer.transfer_plan._model_parts` makes is what
    :func:`facetransfer.region_views.region_textures` would make itself; none of the rig
    where no region is made."""
    from facetransfer.arkit import expression_rig
    from facetransfer.topology import mesh_topology

    topo, rig = tp._model_parts(arkit_model, RewriteOptions())
    own, own_rig = mesh_topology(arkit_model), expression_rig(arkit_model,
                                                               arkit_model.default_weights())
    for f in ("faces", "mouth_faces", "mouth_loop"):
        if hasattr(own, f):
            assert np.array_equal(getattr(topo, f), getattr(own, f)), f
    assert all(np.array_equal(np.asarray(a), np.asarray(b))
               for a, b in zip(vars(rig).values(), vars(own_rig).values()))
    assert tp._model_parts(arkit_model, RewriteOptions(eyes="target", jaw="frame"))[1] is None
    assert tp._made_ahead(None) == (None, None)

