"""Tests of wearfit_usd.io."""
