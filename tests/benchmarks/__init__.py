"""Tests of the benchmark scripts' scoring functions."""
