#!/usr/bin/env python3
"""Checks the Kubernetes manifests of a sharded run (deploy/kubernetes) offline: each against the
API's own schema (kubernetes-validate, which ships the schemas; strict: an unknown field is an
error), then against each other: an Indexed Job whose DC_SHARDS is its `completions`, a merge of as
many shards of the same run, and one volume claim they all mount.

    python3 scripts/check-kubernetes.py [DIR]      # DIR: deploy/kubernetes
"""
import sys
from pathlib import Path

import kubernetes_validate
import yaml

# The first release with backoffLimitPerIndex on by default (beta; 1.28 has it behind a feature gate).
KUBERNETES_VERSION = "1.29.0"


def env_of(job):
    containers = job["spec"]["template"]["spec"]["containers"]
    return {e["name"]: e.get("value") for c in containers for e in c.get("env", [])}


def claims_of(job):
    return {v["persistentVolumeClaim"]["claimName"] for v in job["spec"]["template"]["spec"].get("volumes", [])
            if "persistentVolumeClaim" in v}


def main(folder):
    problems = []
    resources = {}
    for path in sorted(folder.glob("*.yaml")):
        for doc in yaml.safe_load_all(path.read_text()):
            if doc is None:
                continue
            try:
                kubernetes_validate.validate(doc, KUBERNETES_VERSION, strict=True)
            except kubernetes_validate.ValidationError as e:
                where = "/".join(str(p) for p in e.path) or "(top)"
                problems.append(f"{path}: {where}: {e.message}")
                continue
            except kubernetes_validate.SchemaNotFoundError as e:
                problems.append(f"{path}: no schema for {doc.get('apiVersion')} {doc.get('kind')}: {e}")
                continue
            resources[(doc["kind"], doc["metadata"]["name"])] = (path, doc)
    jobs = {name: (p, d) for (kind, name), (p, d) in resources.items() if kind == "Job"}
    indexed = [(p, d) for p, d in jobs.values() if d["spec"].get("completionMode") == "Indexed"]
    merges = [(p, d) for p, d in jobs.values() if d["spec"].get("completionMode") != "Indexed"]
    if not problems and (len(indexed) != 1 or len(merges) != 1):
        problems.append(f"{folder}: expected one Indexed Job (the shards) and one other Job (the merge), "
                        f"found {len(indexed)} and {len(merges)}")
    if not problems:
        (eval_path, shards), (merge_path, merge) = indexed[0], merges[0]
        completions = shards["spec"]["completions"]
        for path, job in [(eval_path, shards), (merge_path, merge)]:
            said = env_of(job).get("DC_SHARDS")
            if said != str(completions):
                problems.append(f"{path}: DC_SHARDS is {said!r} but the Indexed Job runs {completions} shards "
                                f"(completions in {eval_path})")
        if env_of(shards).get("DC_RUN") != env_of(merge).get("DC_RUN"):
            problems.append(f"{merge_path}: DC_RUN {env_of(merge).get('DC_RUN')!r} is not the shards' "
                            f"{env_of(shards).get('DC_RUN')!r}: the merge would read another run")
        claims = {name for (kind, name) in resources if kind == "PersistentVolumeClaim"}
        for path, job in [(eval_path, shards), (merge_path, merge)]:
            for claim in claims_of(job) - claims:
                problems.append(f"{path}: mounts the volume claim {claim!r}, which no manifest here makes")
    for p in problems:
        print(p, file=sys.stderr)
    if problems:
        return 1
    print(f"{folder}: {len(resources)} manifests valid against Kubernetes {KUBERNETES_VERSION}'s schema, "
          f"and consistent")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).parent.parent / "deploy/kubernetes")))
