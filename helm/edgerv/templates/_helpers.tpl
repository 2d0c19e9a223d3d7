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
