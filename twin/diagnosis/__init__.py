"""Diagnosis: residual structure -> candidate effects -> extended model -> before/after (reads only datasets)."""
