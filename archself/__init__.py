"""archself: systems that carry their own architecture as data.

An architecture file (YAML) describes modules, weighted dependency edges,
admissible configurations and actions; archself validates it, compiles it into
runtime modules, simulates scenarios and runs a generic MAPE-K loop that
reconfigures the architecture itself (Franz & Yasin, Algorithm 1).
"""

__version__ = "0.1.0"
