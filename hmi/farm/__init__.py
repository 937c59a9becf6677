"""Running a study's shards on this machine's processes or on a Dask cluster.

A study (a fault campaign, a closed-loop sweep, a soak farm) is cut into **shards**: pieces
of work of 100 ms or more, each computed by a worker from the project's files and plain
options alone, each result independent of which worker ran it and when. The farm sends them
to an executor (:mod:`hmi.farm.executors`: this process, a local process pool, or a Dask
cluster), keeps each finished shard's result on disk (:mod:`hmi.farm.store`: a run stopped
half-way is resumed), and hands the results back in shard order, so the study's merge, and
its report, are the same byte for byte whatever ran them (:mod:`hmi.farm.run`).

What a worker must run is pinned: the project's files, the options and the code version are
fingerprinted (:mod:`hmi.farm.job`, :mod:`hmi.farm.version`), and a worker running other code
is refused before it computes anything (:mod:`hmi.farm.worker`).
"""
