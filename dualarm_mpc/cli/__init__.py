"""The command line, ``dualarm-mpc``."""
