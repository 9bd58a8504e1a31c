"""Peers the benchmarks compare against (only the benchmarks use them): MakeHuman .mhclo fitting."""
