"""The planner as a library: problem, costs, objective, driver, solvers (AICO, R-AICO,
iLQG, the crocoddyl baseline), the compiled sweep kernel. Below the stages, above the plants:
``pipeline -> stages -> planning -> plants``; ``raico/stages/plan`` keeps the plan stage and its tasks."""
