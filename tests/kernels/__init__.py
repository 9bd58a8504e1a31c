"""Tests of wearfit_usd.kernels."""
