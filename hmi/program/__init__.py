"""The scan program: the project's scan lowered once into typed statements (ir), each rule
written once (timers), and the forms printed from it (the Python of the compiled scan:
hmi.engine.codegen.print_program; the reference evaluator: evaluate)."""
