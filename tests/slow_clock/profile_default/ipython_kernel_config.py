# Kernels started with IPYTHONDIR=tests/slow_clock (the nbval run of make test): no history database shared
# between the kernels (the slowed clocks are in startup/00-slow-clock.py)
c = get_config()  # noqa: F821
c.HistoryManager.enabled = False
