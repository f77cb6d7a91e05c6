"""Many clips on Dask distributed: batch tracking, transfer and export (beyond the paper).

Modules, in the order data flows: :mod:`.manifest` (the jobs: clips, pairs, tracks, their names),
:mod:`.chunks` (long clips in overlapping chunks, joined at the seams), :mod:`.jobs` (the tasks
the workers run; :mod:`.model_ref`, the model file each worker loads once), :mod:`.cluster`
(the embedded LocalCluster or a scheduler's client),
:mod:`.digest` (what makes each output, recorded to know it again), :mod:`.ownership` (which
run owns an output: its claim while a job writes it), :mod:`.run` (submit,
collect, skip what is done, stop cleanly; :mod:`.track_submit`, a track run's tasks: counts,
chunks and their claims), :mod:`.summary` (``DIR/summary.csv``).

Typical use::

    from facetransfer.batch import batch_track, clip_jobs, open_client
    from facetransfer.model import load_model

    with open_client(workers=4) as client:
        res = batch_track(clip_jobs(manifest="clips.csv"), "tracks", load_model("m.npz"),
                          client=client, chunk=300)
    print(res.n_failed, res.summary)
"""

from .chunks import Chunk, SeamReport, join_tracks, plan_chunks, seam_difference
from .cluster import open_client, scatter_model
from .manifest import BatchError, ClipJob, ExportJob, PairJob, clip_jobs, export_jobs, pair_jobs
from .run import BatchResult, batch_export, batch_track, batch_transfer
from .summary import Row, read_summary, write_summary

__all__ = ["BatchError", "ClipJob", "PairJob", "ExportJob", "clip_jobs", "pair_jobs",
           "export_jobs", "Chunk", "plan_chunks", "join_tracks", "SeamReport",
           "seam_difference", "open_client", "scatter_model", "BatchResult", "batch_track",
           "batch_transfer", "batch_export", "Row", "read_summary", "write_summary"]
