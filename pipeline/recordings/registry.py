"""Stage name -> its recorder (one module per stage under :mod:`pipeline.recordings`)."""

from __future__ import annotations

from pipeline.recordings.babble import record_babble
from pipeline.recordings.execute import record_execute
from pipeline.recordings.fit import record_fit
from pipeline.recordings.learn import record_learn
from pipeline.recordings.plan import record_plan

RECORDERS = {"babble": record_babble, "plan": record_plan, "execute": record_execute, "fit": record_fit,
             "learn": record_learn}
