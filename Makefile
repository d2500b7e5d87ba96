# Perch: the two commands a newcomer needs are `make demo` and `make test`.
.PHONY: setup test demo bench lock clean
PERCH := .venv/bin/perch

setup:
	@bash tools/setup.sh

test: setup
	@bash tools/run_tests.sh

demo: setup
	@$(PERCH) demo

bench: setup
	@$(PERCH) bench transport --faces 300000 --json

lock:
	@.venv/bin/python tools/lock.py > requirements.lock

clean:
	rm -rf build log install out .venv
