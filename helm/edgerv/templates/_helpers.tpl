{{/* The labels of every object of the release. */}}
{{- define "edgerv.labels" -}}
app.kubernetes.io/name: edgerv
app.kubernetes.io/instance: {{ .Release.Name }}
app.kubernetes.io/managed-by: {{ .Release.Service }}
helm.sh/chart: {{ .Chart.Name }}-{{ .Chart.Version }}
{{- end }}

{{/* The Secret holding the handlers' token (key "token"). */}}
{{- define "edgerv.tokenSecret" -}}
{{- if .Values.token.create }}{{ .Release.Name }}-token{{ else }}{{ required "token.existingSecret is required when token.create is false" .Values.token.existingSecret }}{{ end }}
{{- end }}

{{/* The handlers' ServiceAccount. */}}
{{- define "edgerv.handlerServiceAccount" -}}
{{- if .Values.handler.serviceAccount.create }}{{ .Release.Name }}-handler{{ else }}{{ .Values.handler.serviceAccount.name | default "default" }}{{ end }}
{{- end }}

{{/* The Secret holding the handlers' certificate (keys tls.crt, tls.key, ca.crt). */}}
{{- define "edgerv.tlsSecret" -}}
{{- .Values.tls.existingSecret | default (printf "%s-tls" .Release.Name) }}
{{- end }}

{{/* The name the handlers' certificate carries and the operator verifies. */}}
{{- define "edgerv.tlsServerName" -}}
{{- .Values.tls.serverName | default (printf "%s-handler.%s.svc" .Release.Name .Release.Namespace) }}
{{- end }}

{{/*
The handlers' certificate, its key and the CA (the Secret's data, base64), as JSON. Made
by Helm at install and kept on upgrades (looked up; made again when the server name
changes); made once per render (kept in .Values.tls, so the Secret and the pods'
checksum see the same pair). `helm template` cannot look up: it makes a new pair on
every render (pin one with tls.existingSecret).
*/}}
{{- define "edgerv.tlsData" -}}
{{- if not (hasKey .Values.tls "rendered") }}
{{- $serverName := include "edgerv.tlsServerName" . }}
{{- $old := lookup "v1" "Secret" .Release.Namespace (printf "%s-tls" .Release.Name) }}
{{- $oldName := "" }}
{{- if $old }}{{ $oldName = index ($old.metadata.annotations | default dict) "edgerv.io/server-name" | default "" }}{{ end }}
{{- if and $old (eq $oldName $serverName) }}
{{- $_ := set .Values.tls "rendered" (pick $old.data "ca.crt" "tls.crt" "tls.key") }}
{{- else }}
{{- $ca := genCA (printf "%s edgerv CA" .Release.Name) (int .Values.tls.validityDays) }}
{{- $cert := genSignedCert $serverName nil (list $serverName) (int .Values.tls.validityDays) $ca }}
{{- $_ := set .Values.tls "rendered" (dict "ca.crt" ($ca.Cert | b64enc) "tls.crt" ($cert.Cert | b64enc) "tls.key" ($cert.Key | b64enc)) }}
{{- end }}
{{- end }}
{{- toJson .Values.tls.rendered }}
{{- end }}

{{/* A checksum of the handlers' certificate: a new one rolls the pods that read it. */}}
{{- define "edgerv.tlsChecksum" -}}
{{- if .Values.tls.existingSecret }}
{{- $given := lookup "v1" "Secret" .Release.Namespace .Values.tls.existingSecret }}
{{- ($given.data | default dict) | toJson | sha256sum }}
{{- else }}
{{- include "edgerv.tlsData" . | sha256sum }}
{{- end }}
{{- end }}

{{/* The handlers' API scheme (their probes'). */}}
{{- define "edgerv.scheme" -}}
{{- if .Values.tls.enabled }}HTTPS{{ else }}HTTP{{ end }}
{{- end }}

{{/* An image reference from {repository, tag, digest}: the digest pins it when given. */}}
{{- define "edgerv.image" -}}
{{- if .digest }}{{ .repository }}@{{ .digest }}{{ else }}{{ .repository }}:{{ .tag }}{{ end }}
{{- end }}

{{/* operator.tierLatencyMs as EDGERV_TIER_LATENCY reads it: TIER=MS,... in tier order */}}
{{- define "edgerv.tierLatency" -}}
{{- $pairs := list -}}
{{- range $tier, $ms := .Values.operator.tierLatencyMs -}}
{{- $pairs = append $pairs (printf "%s=%v" $tier $ms) -}}
{{- end -}}
{{- join "," $pairs -}}
{{- end -}}
