"""Independent references for the tests: built from the scenario files and the README's conventions
alone, never from coopsim's own model code."""
