#!/usr/bin/env bash
# Builds the test cluster's binaries from the Go module proxy into a cache kept
# outside the repository (~/.cache/edgerv by default; EDGERV_CACHE overrides it),
# once per version: kube-apiserver, kube-controller-manager, kube-scheduler,
# kubelet and kubectl (k8s.io/kubernetes through the wrapper module in
# gomod/kubernetes), etcd (gomod/etcd), helm, kubeconform, the static pause
# binary, and the JSON schemas kubeconform validates against (k8s_schemas.py,
# from the OpenAPI spec in the k8s.io/kubernetes module's sources).
# With arguments, only those targets: kubernetes, etcd, helm, kubeconform, pause,
# schemas (`build.sh helm kubeconform schemas`: what the chart's render tests need).
# Prints the cache's bin directory on its last line.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
source "$here/versions.env"
edgerv_cache="${EDGERV_CACHE:-$HOME/.cache/edgerv}"
cache="$edgerv_cache/k8s-v$K8S_VERSION"
bin="$cache/bin"
mkdir -p "$bin"
export GOFLAGS="-buildvcs=false -mod=readonly"
export GOTOOLCHAIN=local

log() { echo "cluster build: $*" >&2; }

targets=(kubernetes etcd helm kubeconform pause schemas)
only=("$@")  # none: every target
for t in "${only[@]}"; do
    [[ " ${targets[*]} " == *" $t "* ]] || { log "unknown target $t (the targets: ${targets[*]})"; exit 2; }
done
want() { ((${#only[@]} == 0)) || [[ " ${only[*]} " == *" $1 "* ]]; }
# The k8s.io/kubernetes module's sources (downloaded if the module cache lacks them).
k8s_src() {
    (cd "$here/gomod/kubernetes" && go mod download k8s.io/kubernetes &&
        go list -m -f '{{.Dir}}' k8s.io/kubernetes)
}

k8s_bins=(kube-apiserver kube-controller-manager kube-scheduler kubelet kubectl)
missing=()
if want kubernetes; then
    for b in "${k8s_bins[@]}"; do [[ -x "$bin/$b" ]] || missing+=("$b"); done
fi
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

if want etcd && [[ ! -x "$bin/etcd" ]]; then
    log "compiling etcd v$ETCD_VERSION"
    (cd "$here/gomod/etcd" && go build -trimpath -ldflags "-s -w" -o "$bin/etcd" .)
fi

if want helm && [[ ! -x "$bin/helm" ]]; then
    log "compiling helm v$HELM_VERSION"
    GOBIN="$bin" GOFLAGS=-buildvcs=false go install -trimpath \
        -ldflags "-s -w -X helm.sh/helm/v3/internal/version.version=v$HELM_VERSION" \
        "helm.sh/helm/v3/cmd/helm@v$HELM_VERSION"
fi

# kubeconform prints its version: another one pinned is built anew.
if want kubeconform && [[ "$("$bin/kubeconform" -v 2>/dev/null)" != "v$KUBECONFORM_VERSION" ]]; then
    log "compiling kubeconform v$KUBECONFORM_VERSION"
    GOBIN="$bin" GOFLAGS=-buildvcs=false go install -trimpath \
        -ldflags "-s -w -X main.version=v$KUBECONFORM_VERSION" \
        "github.com/yannh/kubeconform/cmd/kubeconform@v$KUBECONFORM_VERSION"
fi

if want pause && [[ ! -x "$bin/pause" ]]; then
    log "compiling pause"
    src="$(k8s_src)/build/pause/linux/pause.c"
    gcc -Os -static -Wall -Werror -DVERSION="v$K8S_VERSION-edgerv" -o "$bin/pause" "$src"
fi

if want schemas; then
    # Kubernetes' JSON schemas for kubeconform, made once per version from the OpenAPI
    # spec in the module's sources (k8s_schemas.py says where; a no-op when made).
    spec="$(k8s_src)/api/openapi-spec/swagger.json"
    python3 "$here/k8s_schemas.py" kubernetes --swagger "$spec" --version "$K8S_VERSION" \
        --cache "$edgerv_cache" >&2
    # The Prometheus Operator's CRDs (the chart may render a ServiceMonitor), generated
    # from its published API types by controller-gen, as the project itself makes them.
    po="$cache/crds/prometheus-operator-v$PROMETHEUS_OPERATOR_VERSION"
    if [[ ! -s "$po/monitoring.coreos.com_servicemonitors.yaml" ]]; then
        gm="$here/gomod/prometheus-operator"
        types=github.com/prometheus-operator/prometheus-operator/pkg/apis/monitoring
        pinned="$(cd "$gm" && go list -m -f '{{.Version}}' "$types")"
        if [[ "$pinned" != "v$PROMETHEUS_OPERATOR_VERSION" ]]; then
            log "gomod/prometheus-operator pins $pinned, versions.env v$PROMETHEUS_OPERATOR_VERSION"
            exit 1
        fi
        if [[ ! -x "$bin/controller-gen" ]]; then
            log "compiling controller-gen (gomod/prometheus-operator)"
            (cd "$gm" && go build -trimpath -ldflags "-s -w" -o "$bin/controller-gen" \
                sigs.k8s.io/controller-tools/cmd/controller-gen)
        fi
        log "generating the Prometheus Operator's CRDs v$PROMETHEUS_OPERATOR_VERSION"
        mkdir -p "$cache/crds"
        tmp="$(mktemp -d "$cache/crds/.prometheus-operator-XXXXXX")"
        (cd "$gm" && "$bin/controller-gen" crd:crdVersions=v1,maxDescLen=0 \
            paths="$types/v1" output:crd:dir="$tmp") || { rm -rf "$tmp"; exit 1; }
        rm -rf "$po" && mv "$tmp" "$po"
    fi
fi
echo "$bin"
