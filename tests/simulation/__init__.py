"""Tests of the target signature simulation and synthetic missions (SPEC section 4)."""
