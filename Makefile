# The two commands of the README: `make reproduce` and `make test`.
# Each creates .venv from pyproject.toml on first use; nothing else is needed but python3 >= 3.11.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: reproduce test bench clean-venv

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "wmr needs python3 >= 3.11")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

reproduce: $(STAMP)
	$(BIN)/wmr reproduce --out paper

test: $(STAMP)
	$(BIN)/python -m pytest --nbval --nbval-sanitize-with notebooks/sanitize.cfg

bench: $(STAMP)
	$(BIN)/wmr bench --out paper

clean-venv:
	rm -rf $(VENV)
