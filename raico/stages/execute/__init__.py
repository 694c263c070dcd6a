"""The execute stage (:mod:`raico.stages.execute.stage`) and its executions by kind: fixed-base
(:mod:`raico.stages.execute.fixed`), floating (:mod:`raico.stages.execute.floating`) and the whole-body stabilizer
(:mod:`raico.stages.execute.wbc`)."""
