"""pdmpm: Material Point Method with peridynamic bond forces."""

__version__ = "0.1.0"
