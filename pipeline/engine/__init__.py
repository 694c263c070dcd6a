"""The engine: the content-addressed cache, the stage runner, artifacts, executors and progress."""
