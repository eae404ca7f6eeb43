"""Tests of roadbev_core.ride."""
