"""The weld job: what it is given and returns, the checks before any motion, the stud order, the sequence."""
