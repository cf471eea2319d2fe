"""Monte-Carlo accuracy studies on dask.distributed: error distributions, Cramér-Rao bounds, coverage, design of experiments."""
