"""Tests of wearfit_usd.render."""
