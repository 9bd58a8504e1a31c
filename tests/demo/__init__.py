"""Tests of wearfit_usd.demo."""
