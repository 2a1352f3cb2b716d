#!/usr/bin/env bash
# Build the airpuff image (docker/Dockerfile) from the repository's sources.
#
#   docker/build.sh [--tag airpuff:local] [--base IMAGE] [--network MODE] [--ca-bundle FILE]
#
# The base: --base IMAGE if given; else python:3.11-slim where a registry serves it (or it is
# already here); else a Python base made from Debian's own packages (bookworm: Python 3.11) with
# mmdebstrap and `docker import`, tagged airpuff-python:bookworm and reused by later builds
# (making it needs root and mmdebstrap; about 1-3 minutes).
# --network MODE is given to `docker build` (`host` where containers reach the package index only
# through the host's network); --ca-bundle FILE is the CA bundle pip must trust (where the index
# is reached through a TLS proxy), used during the build and left out of the image.
# The build context is only what the image installs (pyproject.toml, README.md, airpuff_core/,
# sweep/, api/), sent as a tar stream, so this works with the classic builder and BuildKit alike.
set -euo pipefail
cd "$(dirname "$0")/.."

tag=airpuff:local
base=""
network=""
ca_bundle=""
debian_base=airpuff-python:bookworm
usage() { echo "usage: docker/build.sh [--tag T] [--base IMAGE] [--network MODE] [--ca-bundle FILE]" >&2; exit 2; }
while [ $# -gt 0 ]; do
    case "$1" in
        --tag) tag=${2:?}; shift 2 ;;
        --base) base=${2:?}; shift 2 ;;
        --network) network=${2:?}; shift 2 ;;
        --ca-bundle) ca_bundle=${2:?}; shift 2 ;;
        *) usage ;;
    esac
done
if [ -n "$ca_bundle" ] && [ ! -r "$ca_bundle" ]; then
    echo "docker/build.sh: --ca-bundle $ca_bundle: no such readable file" >&2; exit 2
fi

if [ -z "$base" ]; then
    if docker image inspect python:3.11-slim >/dev/null 2>&1 \
       || docker pull -q python:3.11-slim >/dev/null 2>&1; then
        base=python:3.11-slim
    else
        base=$debian_base
        if ! docker image inspect "$base" >/dev/null 2>&1; then
            if ! command -v mmdebstrap >/dev/null || [ "$(id -u)" != 0 ]; then
                echo "docker/build.sh: python:3.11-slim cannot be pulled, and making a Debian base needs root and mmdebstrap (apt-get install mmdebstrap); or give --base IMAGE" >&2
                exit 1
            fi
            echo "docker/build.sh: python:3.11-slim cannot be pulled; making $base from Debian's packages" >&2
            tmp=$(mktemp -d)
            trap 'rm -rf "$tmp"' EXIT
            mmdebstrap --quiet --variant=minbase \
                --include=python3,python3-venv,python3-pip,ca-certificates \
                bookworm "$tmp/base.tar"
            docker import --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
                --change 'ENV LANG=C.UTF-8' --change 'CMD ["python3"]' "$tmp/base.tar" "$base" >/dev/null
            rm -rf "$tmp"
        fi
    fi
fi

build_args=(--force-rm --build-arg "PYTHON_IMAGE=$base" -f docker/Dockerfile -t "$tag")
[ -n "$network" ] && build_args+=(--network "$network")

# The context: the files the Dockerfile copies, plus the CA bundle as pip-ca.crt if given.
files=(pyproject.toml README.md airpuff_core sweep api docker/Dockerfile)
extra=()
if [ -n "$ca_bundle" ]; then
    ca_dir=$(mktemp -d)
    trap 'rm -rf "$ca_dir"' EXIT
    cp -L "$ca_bundle" "$ca_dir/pip-ca.crt"
    extra=(-C "$ca_dir" pip-ca.crt)
fi
echo "docker/build.sh: building $tag on $base" >&2
start=$(date +%s)
tar -c --exclude=__pycache__ --exclude='*.pyc' "${files[@]}" "${extra[@]}" \
    | docker build "${build_args[@]}" -
echo "docker/build.sh: $tag built in $(( $(date +%s) - start )) s ($(docker image inspect -f '{{.Size}}' "$tag" | awk '{printf "%.0f MB", $1 / 1e6}'))" >&2
