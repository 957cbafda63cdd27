"""Tools around the library: `svrpo bench` and its timing helpers, the allocator settings.
"""
