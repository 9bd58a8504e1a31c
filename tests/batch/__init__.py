"""Tests of wearfit_usd.batch."""
