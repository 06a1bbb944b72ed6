"""cab's Rerun export: one attempt's record (observations, video, snapshots, calls, programs,
checkpoints) as a Rerun recording, ``attempt.rrd`` in the attempt's folder."""
