"""Stage name -> its recorder (one module per stage under :mod:`raico.pipeline.recordings`)."""

from __future__ import annotations

from raico.pipeline.recordings.babble import record_babble
from raico.pipeline.recordings.execute import record_execute
from raico.pipeline.recordings.fit import record_fit
from raico.pipeline.recordings.learn import record_learn
from raico.pipeline.recordings.plan import record_plan

RECORDERS = {"babble": record_babble, "plan": record_plan, "execute": record_execute, "fit": record_fit,
             "learn": record_learn}
