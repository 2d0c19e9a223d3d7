//go:build tools

// What build.sh runs: controller-gen over the Prometheus Operator's API types; this file
// only pins them in go.mod.
package tools

import (
	_ "github.com/prometheus-operator/prometheus-operator/pkg/apis/monitoring/v1"
	_ "sigs.k8s.io/controller-tools/cmd/controller-gen"
)
