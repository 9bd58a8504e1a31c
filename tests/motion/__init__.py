"""Tests of wearfit_usd.motion."""
