"""Tests of wearfit_usd.animate."""
