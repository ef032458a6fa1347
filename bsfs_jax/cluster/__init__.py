"""Studies beyond one machine: independent chunks of work on a Dask cluster.

bsfs's long jobs are many independent tasks. `Cluster` sends them to the workers of a
Dask cluster (`Cluster(scheduler=ADDRESS)`, `Cluster(workers=N)` for a local one;
`open_cluster` reads `BSFS_SCHEDULER` too), each chunk one single-host JAX program in a
worker process; the results come back to this process, which alone writes the output
folder. `Cluster.run` is the `runner=` of `bsfs_jax.analysis.atlas` (one row per chunk)
and `bsfs_jax.analysis.sweep` (a cold sweep's chunks, then its verification's). A worker
that dies loses only its chunk, which runs again elsewhere; a chunk that fails twice is
reported with its cause while the others complete. Workers share one persistent
compilation cache, one folder per CPU kind (`host_cache_dir`), and need the same bsfs
(and jax) as the client: the chunks' functions travel by reference to its modules.

    with Cluster(workers=2) as cluster:
        result = sweep(problem, values, config=config, verify=verify, runner=cluster.run)

Dask (`pip install 'bsfs[cluster]'`) is imported only when a cluster is opened.
"""

from ._host_key import cache_root as cache_root
from ._host_key import cpu_key as cpu_key
from ._host_key import host_cache_dir as host_cache_dir
from ._run import ENV as ENV
from ._run import ChunkFailed as ChunkFailed
from ._run import Cluster as Cluster
from ._run import open_cluster as open_cluster
from ._run import summary as summary
from ._worker import ready as ready
from ._worker import run_chunk as run_chunk

__all__ = ["ENV", "ChunkFailed", "Cluster", "cache_root", "cpu_key",
           "host_cache_dir", "open_cluster", "ready", "run_chunk", "summary"]
