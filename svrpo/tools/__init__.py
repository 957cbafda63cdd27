"""Tools around the library: `svrpo bench` and its timing helpers for benchmarks/.
"""
