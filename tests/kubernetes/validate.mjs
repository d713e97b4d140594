// Validates Kubernetes objects (a multi-document YAML file, as `kubectl kustomize` prints it)
// strictly, in two ways, and exits non-zero naming every problem:
//  1. kubernetes-models 4.5.1 validates each object against the API's OpenAPI schema (types,
//     required fields, enums, formats). Its schemas are Kubernetes 1.33's; no release of it
//     carries 1.30's (4.4.x is 1.27.1, 5.x is 1.36 and needs Node 22), and 1.33 only adds.
//  2. Every field must exist in Kubernetes 1.30: the field sets of @kubernetes/client-node
//     0.22.3's models, generated from the 1.30 OpenAPI spec, walked recursively. A typo or a
//     field newer than 1.30 is refused (the API server would drop or refuse it).
// usage: node validate.mjs RENDERED.yaml
import fs from "node:fs";
import { createRequire } from "node:module";
import YAML from "yaml";

const require = createRequire(import.meta.url);
const k8s130 = require("@kubernetes/client-node");

const [file] = process.argv.slice(2);
const docs = YAML.parseAllDocuments(fs.readFileSync(file, "utf8")).map((d) => d.toJS()).filter(Boolean);
const problems = [];

// kind -> the 1.30 model class name and the kubernetes-models module.
const KINDS = {
  "v1/Secret": ["V1Secret", "kubernetes-models/v1/Secret"],
  "v1/Service": ["V1Service", "kubernetes-models/v1/Service"],
  "v1/PersistentVolumeClaim": ["V1PersistentVolumeClaim", "kubernetes-models/v1/PersistentVolumeClaim"],
  "v1/ConfigMap": ["V1ConfigMap", "kubernetes-models/v1/ConfigMap"],
  "apps/v1/Deployment": ["V1Deployment", "kubernetes-models/apps/v1/Deployment"],
  "batch/v1/Job": ["V1Job", "kubernetes-models/batch/v1/Job"],
  "policy/v1/PodDisruptionBudget": ["V1PodDisruptionBudget", "kubernetes-models/policy/v1/PodDisruptionBudget"],
};

function fields(typeName) {
  const cls = k8s130[typeName];
  if (!cls || typeof cls.getAttributeTypeMap !== "function") return null;
  return new Map(cls.getAttributeTypeMap().map((a) => [a.baseName, a.type]));
}

// Walks `value` as a `type` of the 1.30 models: unknown keys are problems.
function walk(value, type, where) {
  if (value === null || value === undefined) return;
  let m = /^Array<(.+)>$/.exec(type);
  if (m) {
    if (!Array.isArray(value)) return problems.push(`${where}: a list was expected`);
    return value.forEach((v, i) => walk(v, m[1], `${where}[${i}]`));
  }
  m = /^\{ \[key: string\]: (.+); \}$/.exec(type);
  if (m) {
    if (typeof value !== "object") return problems.push(`${where}: a map was expected`);
    return Object.entries(value).forEach(([k, v]) => walk(v, m[1], `${where}.${k}`));
  }
  const f = fields(type);
  if (!f) return;  // a scalar (string, number, boolean, Date, IntOrString, object)
  if (typeof value !== "object" || Array.isArray(value)) return problems.push(`${where}: an object (${type}) was expected`);
  for (const [k, v] of Object.entries(value)) {
    if (!f.has(k)) problems.push(`${where}.${k}: no such field in Kubernetes 1.30's ${type}`);
    else walk(v, f.get(k), `${where}.${k}`);
  }
}

for (const obj of docs) {
  // kustomize folds a Secret's base64 into 76-column lines; the API server's decoder (Go's
  // encoding/base64) skips the line breaks, the schema's "byte" format does not.
  if (obj.kind === "Secret" && obj.data)
    for (const k of Object.keys(obj.data)) obj.data[k] = String(obj.data[k]).replace(/\s+/g, "");
  const key = `${obj.apiVersion}/${obj.kind}`;
  const name = `${obj.kind}/${obj.metadata?.name}`;
  if (!KINDS[key]) {
    problems.push(`${name}: ${key} is not a kind this check knows`);
    continue;
  }
  const [model, module] = KINDS[key];
  walk(obj, model, name);
  const { [module.split("/").pop()]: Model } = await import(module);
  try {
    new Model(obj).validate();
  } catch (e) {
    problems.push(`${name}: ${e.message}`);
  }
}
// 3. What the deployment must hold beyond the schema: every volume a container mounts is
// defined, every claim and Secret a pod names is rendered too, images are pinned (no
// :latest), containers have requests and limits and run non-root on a read-only root.
const rendered = (kind) => new Set(docs.filter((d) => d.kind === kind).map((d) => d.metadata.name));
const claims = rendered("PersistentVolumeClaim"), secrets = rendered("Secret");
for (const obj of docs) {
  const pod = obj.spec?.template?.spec;
  if (!pod) continue;
  const name = `${obj.kind}/${obj.metadata.name}`;
  const volumes = new Map((pod.volumes || []).map((v) => [v.name, v]));
  for (const v of volumes.values()) {
    if (v.persistentVolumeClaim && !claims.has(v.persistentVolumeClaim.claimName))
      problems.push(`${name}: volume ${v.name} claims ${v.persistentVolumeClaim.claimName}, which is not defined`);
    if (v.secret && !secrets.has(v.secret.secretName))
      problems.push(`${name}: volume ${v.name} mounts the Secret ${v.secret.secretName}, which is not defined`);
  }
  if (pod.securityContext?.runAsNonRoot !== true) problems.push(`${name}: the pod does not set runAsNonRoot`);
  for (const c of [...(pod.initContainers || []), ...pod.containers]) {
    const where = `${name} container ${c.name}`;
    for (const m of c.volumeMounts || [])
      if (!volumes.has(m.name)) problems.push(`${where}: mounts ${m.name}, which the pod does not define`);
    for (const e of c.env || []) {
      const ref = e.valueFrom?.secretKeyRef;
      if (ref && !secrets.has(ref.name)) problems.push(`${where}: env ${e.name} reads the Secret ${ref.name}, which is not defined`);
    }
    if (!/:[^/]+$/.test(c.image) || c.image.endsWith(":latest")) problems.push(`${where}: image ${c.image} is not pinned to a version`);
    if (!c.resources?.requests || !c.resources?.limits) problems.push(`${where}: no resource requests and limits`);
    if (c.securityContext?.readOnlyRootFilesystem !== true) problems.push(`${where}: the root filesystem is writable`);
    if (c.securityContext?.allowPrivilegeEscalation !== false) problems.push(`${where}: privilege escalation is allowed`);
  }
}
if (docs.length === 0) problems.push(`${file} holds no object`);
if (problems.length) {
  console.error(`${problems.length} problems:\n  ` + problems.join("\n  "));
  process.exit(1);
}
console.log(`${docs.length} objects valid: ${docs.map((d) => `${d.kind}/${d.metadata.name}`).join(", ")}`);
