# Convenience targets; the scripts do the work (they need only bash and python3).
.PHONY: demo test bench lint
demo:
	bash scripts/demo.sh
test:
	bash scripts/test.sh
bench:
	bash scripts/bootstrap.sh && .venv/bin/python bench/benchmarks/bench_dynamics.py
lint:
	.venv/bin/ruff check .
