# The two commands of the README: `make demo` and `make test`. Both build .venv themselves.
# `make test-docker`: the tests that need a Docker engine (below).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip

.PHONY: demo test test-docker lint clean experiments

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet -e '.[test]'
	@# the sources' bytecode, written once (an editable install leaves that to the first import, which
	@# does not write it where PYTHONDONTWRITEBYTECODE is set: every process would compile them again)
	$(PY) -m compileall -q shared services >/dev/null
	touch $@

# tests/test_remote.py's base install (`pip install .` in a fresh venv, offline: --no-index) takes its wheels from
# here: the base requirements' and the build's (pyproject.toml [build-system]), downloaded once.
$(VENV)/wheelhouse/.complete: pyproject.toml $(VENV)/.installed
	rm -rf $(VENV)/wheelhouse
	$(PIP) download --quiet --dest $(VENV)/wheelhouse . 'setuptools>=77' wheel
	touch $@

.venv: $(VENV)/.installed $(VENV)/wheelhouse/.complete

demo: .venv
	$(VENV)/bin/cdpr run caroca_15kg --rrd runs/caroca_15kg.rrd --summary runs/caroca_15kg.summary.json

# The whole suite on every core (pytest-xdist: TEST_JOBS workers, each module on one worker, the costly ones
# first: tests/conftest.py), then the 20 slowest tests. TEST_JOBS=0: one process.
TEST_JOBS ?= auto
test: .venv
	$(PY) -m pytest -n $(TEST_JOBS) --dist loadscope --durations=20 $(PYTEST_ARGS)

# `make test-docker`: tests/test_docker.py (pytest -m docker; `make test` leaves them out): builds the
# three images of docker/Dockerfile and runs compose sessions end to end. BASE is the images' base:
# given, or python:3.11-slim when the engine has it or can pull it, or else the stand-in that
# $(LOCAL_BASE_SH) builds from Debian packages (it also installs and starts an engine and Compose
# where there are none, as root). Without an engine the tests skip, saying why. CDPR_COMPOSE picks
# the Compose to test ("docker compose" or docker-compose; default: v2 when installed).
BASE ?=
LOCAL_BASE_SH ?= ../shared/docker/local-base.sh
test-docker: .venv
	@base="$(BASE)"; \
	if [ -z "$$base" ] && ! docker info >/dev/null 2>&1 && [ -f "$(LOCAL_BASE_SH)" ] && [ "$$(id -u)" = 0 ]; then \
	  base=$$(bash "$(LOCAL_BASE_SH)") || exit 1; \
	fi; \
	if [ -z "$$base" ] && docker info >/dev/null 2>&1; then \
	  if docker image inspect python:3.11-slim >/dev/null 2>&1 \
	     || timeout 300 docker pull -q python:3.11-slim >/dev/null 2>&1; then base=python:3.11-slim; \
	  elif [ -f "$(LOCAL_BASE_SH)" ]; then base=$$(bash "$(LOCAL_BASE_SH)") || exit 1; \
	  else echo "make test-docker: python:3.11-slim cannot be pulled and $(LOCAL_BASE_SH) is missing: give BASE=IMAGE" >&2; exit 1; \
	  fi; \
	fi; \
	echo "make test-docker: base image $${base:-none (no Docker engine)}"; \
	CDPR_BASE="$$base" $(PY) -m pytest -m docker tests/test_docker.py $(PYTEST_ARGS)

# `make lint`: ruff, the import contracts and the type check ([tool.ruff], [tool.importlinter], [tool.mypy] in
# pyproject.toml); fails on the first that finds anything (tests/test_lint.py runs it).
lint: .venv
	$(VENV)/bin/ruff check .
	$(VENV)/bin/lint-imports --no-cache
	$(VENV)/bin/mypy

clean:
	rm -rf $(VENV) runs build *.egg-info

# `make certs`: the secrets of the secure Zenoh profile (docs/security.md) in $(CERTS_DIR): a private CA,
# the router's TLS certificate (valid for CERT_HOSTS: add the names/addresses remote machines use),
# and one random password per identity, as the router's dictionary (users.txt) and one client config
# per identity (<name>.json5). The identities are those of `cdpr acl --identities` (the topic tables' roles,
# observer, ros2-controller); SESSIONS=labA,labB adds controller.<S> and ros2-controller.<S> for each session S
# and writes the router config that knows them ($(CERTS_DIR)/router-secure.json5: `cdpr acl --sessions`).
# The directory is private (0700); its files but the CA key are world-readable inside it, so that containers
# can read the ones bind-mounted into them. Nothing is overwritten (delete the directory to start again).
# Needs openssl, and the virtualenv (made if missing).
CERTS_DIR ?= docker/secrets
CERT_HOSTS ?= DNS:router,DNS:localhost,IP:127.0.0.1
CERT_DAYS ?= 825
SESSIONS ?=

.PHONY: certs
certs:
	@if [ -e $(CERTS_DIR)/ca.pem ]; then echo "$(CERTS_DIR)/ca.pem exists: keeping it (delete $(CERTS_DIR) to start again)"; exit 0; fi; \
	[ -x $(PY) ] || $(MAKE) --no-print-directory .venv >&2; \
	users=$$($(PY) -m cdpr acl --identities --sessions "$(SESSIONS)") || exit 2; \
	set -e; umask 077; mkdir -p $(CERTS_DIR); \
	if [ -n "$(SESSIONS)" ]; then $(PY) -m cdpr acl --sessions "$(SESSIONS)" -o $(CERTS_DIR)/router-secure.json5; fi; \
	cd $(CERTS_DIR); echo '*' > .gitignore; \
	openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out ca.key; \
	openssl req -x509 -new -key ca.key -sha256 -days $(CERT_DAYS) -subj "/CN=cdpr session CA" -out ca.pem \
	  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign"; \
	openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out router.key; \
	openssl req -new -key router.key -subj "/CN=router" -out router.csr; \
	printf 'basicConstraints=CA:FALSE\nkeyUsage=digitalSignature\nextendedKeyUsage=serverAuth\nsubjectAltName=%s\n' \
	  "$(CERT_HOSTS)" > router.ext; \
	openssl x509 -req -in router.csr -CA ca.pem -CAkey ca.key -CAcreateserial -days $(CERT_DAYS) -sha256 \
	  -extfile router.ext -out router.pem 2>/dev/null; \
	rm -f router.csr router.ext ca.srl; : > users.txt; \
	for user in $$users; do \
	  password=$$(openssl rand -hex 24); echo "$$user:$$password" >> users.txt; \
	  printf '%s\n' "// Zenoh identity \"$$user\" of the cdpr secure profile (generated by make certs; keep it secret)." \
	    "{" "  mode: \"client\"," "  transport: {" \
	    "    link: { tls: { root_ca_certificate: \"secrets/ca.pem\" } }," \
	    "    auth: { usrpwd: { user: \"$$user\", password: \"$$password\" } }," "  }," "}" > $$user.json5; \
	done; \
	chmod 644 ca.pem router.pem router.key users.txt *.json5; \
	echo "wrote $(CERTS_DIR): ca.pem ca.key router.pem router.key users.txt and an identity each:" $$users

experiments: .venv
	$(VENV)/bin/cdpr experiments
