"""Tests of wearfit_usd.dress."""
