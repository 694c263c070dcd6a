"""The engine: the content-addressed cache (keys, atomic files, locks, the cache), the stage runner,
artifacts, executors and progress."""
