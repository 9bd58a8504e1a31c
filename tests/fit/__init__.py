"""Tests of wearfit_usd.fit."""
