#!/usr/bin/env bash
# Builds the test cluster's binaries from the Go module proxy into a cache kept
# outside the repository (~/.cache/edgerv by default; EDGERV_CACHE overrides it),
# once per version: kube-apiserver, kube-controller-manager, kube-scheduler,
# kubelet and kubectl (k8s.io/kubernetes through the wrapper module in
# gomod/kubernetes), etcd (gomod/etcd), helm, and the static pause binary.
# Prints the cache's bin directory on its last line.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
source "$here/versions.env"
cache="${EDGERV_CACHE:-$HOME/.cache/edgerv}/k8s-v$K8S_VERSION"
bin="$cache/bin"
mkdir -p "$bin"
export GOFLAGS="-buildvcs=false -mod=readonly"
export GOTOOLCHAIN=local

log() { echo "cluster build: $*" >&2; }

k8s_bins=(kube-apiserver kube-controller-manager kube-scheduler kubelet kubectl)
missing=()
for b in "${k8s_bins[@]}"; do [[ -x "$bin/$b" ]] || missing+=("$b"); done
if ((${#missing[@]})); then
    log "compiling Kubernetes v$K8S_VERSION: ${missing[*]} (the first time on a machine: about 11 min on 2 cores, module downloads included)"
    pkg="k8s.io/component-base/version"
    cli="k8s.io/client-go/pkg/version"
    date="$(date -u +%Y-%m-%dT%H:%M:%SZ)"
    ld="-s -w"
    minor="$(cut -d. -f2 <<<"$K8S_VERSION")"
    for p in "$pkg" "$cli"; do
        ld+=" -X $p.gitVersion=v$K8S_VERSION -X $p.gitMajor=1 -X $p.gitMinor=$minor"
        ld+=" -X $p.gitTreeState=clean -X $p.buildDate=$date"
    done
    pkgs=()
    for b in "${missing[@]}"; do pkgs+=("k8s.io/kubernetes/cmd/$b"); done
    (cd "$here/gomod/kubernetes" && go build -v -tags selinux,notest -trimpath -ldflags "$ld" -o "$bin/" "${pkgs[@]}") 2>&1 \
        | awk '{n++; if (n % 200 == 0) printf "cluster build:   %d packages compiled (%s)\n", n, $0 > "/dev/stderr"}'
    for b in "${missing[@]}"; do [[ -x "$bin/$b" ]] || { log "failed to build $b"; exit 1; }; done
fi

if [[ ! -x "$bin/etcd" ]]; then
    log "compiling etcd v$ETCD_VERSION"
    (cd "$here/gomod/etcd" && go build -trimpath -ldflags "-s -w" -o "$bin/etcd" .)
fi

if [[ ! -x "$bin/helm" ]]; then
    log "compiling helm v$HELM_VERSION"
    GOBIN="$bin" GOFLAGS=-buildvcs=false go install -trimpath \
        -ldflags "-s -w -X helm.sh/helm/v3/internal/version.version=v$HELM_VERSION" \
        "helm.sh/helm/v3/cmd/helm@v$HELM_VERSION"
fi

if [[ ! -x "$bin/pause" ]]; then
    log "compiling pause"
    src="$(cd "$here/gomod/kubernetes" && go list -m -f '{{.Dir}}' k8s.io/kubernetes)/build/pause/linux/pause.c"
    gcc -Os -static -Wall -Werror -DVERSION="v$K8S_VERSION-edgerv" -o "$bin/pause" "$src"
fi
echo "$bin"
