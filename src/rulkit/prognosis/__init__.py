"""Prognosis: propagation to a failure threshold and RUL distributions."""
