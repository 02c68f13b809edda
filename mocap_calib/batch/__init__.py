"""Many sessions at once: a manifest of sessions, an engine that runs them (a local process
pool, or Dask for a cluster), results written atomically and skipped when unchanged, and a
fleet history per IMU.

``engine`` runs any picklable function over a list of jobs (scripts use it for their studies);
``manifest`` reads and checks the batch file; ``runner`` calibrates the sessions; ``fleet``
relates the results of one IMU over dates. Dask is imported only by the Dask engine.
"""
