"""Recordings derived from a stage's stored data: ``recording.rrd`` (Rerun) and ``trajectory.mcap``.

A recorder is ``recorder(folder, artifact, inputs, lookup)``, one module per stage (``babble``, ``plan``,
``execute``, ``fit``, ``learn``; :data:`raico.pipeline.recordings.registry.RECORDERS`): it reads the entry's data
files (and its inputs', e.g. the plan of an execution; ``lookup(stage, key)`` gives any other entry of the
same cache, e.g. a learn entry's episodes) and writes the recording files into ``folder``;
the cache moves them beside the data (``Cache.write_derived``). Because recordings are made
from the data, a run first made with ``--no-record`` gets its recording later without
recomputing, and the recording is never part of the data's cache key.

Each stage has its own blueprint (``raico.pipeline.recordings.rerun_io.stage_blueprint``): the robot on the
left, the plots that matter on the right, on ``sim_time``, where the file opens; and its own
application id per stage, plant and task (``raico.pipeline.recordings.rerun_io.application_id``), since a viewer
shows every recording of one application id in one layout.

Execute recordings plot ``task/<name>/value`` (executed) against ``task/<name>/planned`` and the
targets in one view per task map, the tracking error, the joints and torques by limb, the
status and the events; babble and fit recordings follow the same layout. Learn recordings
(``raico/pipeline/recordings/learn.py``) plot the loop's quantities per episode on ``episode``.
"""

RECORDING = "recording.rrd"
MCAP = "trajectory.mcap"
