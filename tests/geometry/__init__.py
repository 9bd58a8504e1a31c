"""Tests of wearfit_usd.geometry."""
