"""`ffviz bench`, the benchmark harness, apart from the product's modules: ``command`` (the command: clips, the
schedule, the rows), ``methods`` (ffviz's modes and the peer stabilizers it compares), ``measure`` (one child process
measured from outside; the benchmarks in benchmarks/ use it too), ``report`` (the table, the raw results, the plot and
the dated report) and ``profile`` (``--profile``: CPU a frame by stage).
"""
