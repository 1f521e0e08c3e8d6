"""Behaviours beyond the serve library: the CMA-ES search over a domain's skill parameters (``cma``) and ζσ as a
smooth function of those parameters (``surface``). The agent that uses them is ``rba.interact.generating_agent``."""
