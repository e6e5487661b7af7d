//! The Kubernetes manifests in deploy/k8s, checked without a cluster: every document
//! parses, has the fields its kind requires (a small schema per kind), and the pieces
//! refer to each other consistently (selectors, ports, Secrets, the autoscaler's target,
//! the container arguments the `paddock` binary accepts).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn manifests() -> Vec<(PathBuf, Value)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/k8s");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("deploy/k8s")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    files.sort();
    let mut docs = Vec::new();
    for f in files {
        let text = std::fs::read_to_string(&f).expect("manifest");
        for doc in serde_norway::Deserializer::from_str(&text) {
            let v: Value = serde::Deserialize::deserialize(doc)
                .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            if !v.is_null() {
                docs.push((f.clone(), v));
            }
        }
    }
    docs
}

/// Dotted paths that must exist (and not be null) in a document of each kind.
fn required(kind: &str) -> &'static [&'static str] {
    match kind {
        "Namespace" => &["metadata.name"],
        "Secret" => &["metadata.name", "metadata.namespace", "type"],
        "Service" => &["metadata.name", "spec.selector", "spec.ports"],
        "StatefulSet" => &[
            "metadata.name",
            "spec.serviceName",
            "spec.replicas",
            "spec.selector.matchLabels",
            "spec.template.metadata.labels",
            "spec.template.spec.containers",
            "spec.template.spec.securityContext.runAsNonRoot",
            "spec.volumeClaimTemplates",
        ],
        "Deployment" => &[
            "metadata.name",
            "spec.selector.matchLabels",
            "spec.template.metadata.labels",
            "spec.template.spec.containers",
            "spec.template.spec.securityContext.runAsNonRoot",
        ],
        "HorizontalPodAutoscaler" => &[
            "spec.scaleTargetRef.kind",
            "spec.scaleTargetRef.name",
            "spec.minReplicas",
            "spec.maxReplicas",
            "spec.metrics",
        ],
        other => panic!("unexpected kind {other}"),
    }
}

fn get<'a>(v: &'a Value, path: &str) -> Option<&'a Value> {
    path.split('.')
        .try_fold(v, |v, k| v.get(k))
        .filter(|v| !v.is_null())
}

#[test]
fn manifests_follow_the_schema_and_refer_to_each_other() {
    let docs = manifests();
    let mut by_kind: BTreeMap<String, Vec<&Value>> = BTreeMap::new();
    for (file, d) in &docs {
        let api = d["apiVersion"]
            .as_str()
            .unwrap_or_else(|| panic!("{}: no apiVersion", file.display()));
        let kind = d["kind"]
            .as_str()
            .unwrap_or_else(|| panic!("{}: no kind", file.display()));
        let want_api = match kind {
            "StatefulSet" | "Deployment" => "apps/v1",
            "HorizontalPodAutoscaler" => "autoscaling/v2",
            _ => "v1",
        };
        assert_eq!(api, want_api, "{}: {kind} apiVersion", file.display());
        for p in required(kind) {
            assert!(get(d, p).is_some(), "{}: {kind} lacks {p}", file.display());
        }
        by_kind.entry(kind.to_string()).or_default().push(d);
    }
    for k in [
        "Namespace",
        "Secret",
        "Service",
        "StatefulSet",
        "Deployment",
        "HorizontalPodAutoscaler",
    ] {
        assert!(by_kind.contains_key(k), "no {k} in deploy/k8s");
    }
    let secrets: BTreeSet<&str> = by_kind["Secret"]
        .iter()
        .filter_map(|s| s["metadata"]["name"].as_str())
        .collect();

    for kind in ["StatefulSet", "Deployment"] {
        for w in &by_kind[kind] {
            let name = w["metadata"]["name"].as_str().unwrap_or_default();
            assert_eq!(
                w["spec"]["selector"]["matchLabels"], w["spec"]["template"]["metadata"]["labels"],
                "{name}: the selector must match the pod labels"
            );
            let pod = &w["spec"]["template"]["spec"];
            for v in pod["volumes"].as_array().into_iter().flatten() {
                if let Some(s) = v["secret"]["secretName"].as_str() {
                    assert!(secrets.contains(s), "{name} mounts missing Secret {s}");
                }
            }
            for c in pod["containers"].as_array().expect("containers") {
                let image = c["image"].as_str().unwrap_or_default();
                assert!(image.starts_with("paddock-"), "{name}: image {image}");
                // the container arguments are ones the paddock binary accepts
                let args: Vec<&str> = c["args"]
                    .as_array()
                    .expect("args")
                    .iter()
                    .filter_map(Value::as_str)
                    .collect();
                let out = Command::new(paddock_e2e::paddock_bin())
                    .args(&args[..1])
                    .arg("--help")
                    .output()
                    .expect("paddock --help");
                let help = String::from_utf8_lossy(&out.stdout);
                for flag in args.iter().filter(|a| a.starts_with("--")) {
                    assert!(
                        help.contains(flag),
                        "{name}: `paddock {}` has no {flag}",
                        args[0]
                    );
                }
                for probe in ["livenessProbe", "readinessProbe"] {
                    if let Some(cmd) = c[probe]["exec"]["command"].as_array() {
                        assert_eq!(cmd[0], "/paddock", "{name}: {probe}");
                        assert_eq!(cmd[1], "health", "{name}: {probe}");
                    }
                }
                assert!(c["livenessProbe"].is_object(), "{name}: no liveness probe");
            }
        }
    }
    // the Service selects the broker's pods and exposes its named ports
    let sts = by_kind["StatefulSet"][0];
    let svc = by_kind["Service"]
        .iter()
        .find(|s| s["metadata"]["name"] == sts["spec"]["serviceName"])
        .expect("the StatefulSet's Service");
    assert_eq!(
        svc["spec"]["selector"],
        sts["spec"]["selector"]["matchLabels"]
    );
    let container_ports: BTreeSet<&str> = sts["spec"]["template"]["spec"]["containers"][0]["ports"]
        .as_array()
        .expect("broker ports")
        .iter()
        .filter_map(|p| p["name"].as_str())
        .collect();
    for p in svc["spec"]["ports"].as_array().expect("ports") {
        let target = p["targetPort"].as_str().expect("named targetPort");
        assert!(
            container_ports.contains(target),
            "Service targets unknown port {target}"
        );
    }
    // the autoscaler scales the worker Deployment on CPU
    let hpa = by_kind["HorizontalPodAutoscaler"][0];
    let dep = by_kind["Deployment"][0];
    assert_eq!(hpa["spec"]["scaleTargetRef"]["kind"], "Deployment");
    assert_eq!(
        hpa["spec"]["scaleTargetRef"]["name"],
        dep["metadata"]["name"]
    );
    assert_eq!(hpa["spec"]["metrics"][0]["resource"]["name"], "cpu");
    assert!(
        dep["spec"]["template"]["spec"]["containers"][0]["resources"]["requests"]["cpu"]
            .is_string(),
        "CPU autoscaling needs a CPU request on the workers"
    );
}
