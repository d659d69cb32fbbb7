"""Coverage of awl pierce's predicted 95 % bounds over awl trial runs (their trial.json), and what scaling the located covariance (k) or the model sigma would give. Usage: coverage.py DIR"""
import glob, json, sys
import numpy as np
rows = []
for f in sorted(glob.glob(sys.argv[1] + '/*/trial.json')):
    d = json.load(open(f))
    for r in d['rows']:
        r['run'] = f.split('/')[-2]
        rows.append(r)
print(len(rows), 'targets from', len(set(r['run'] for r in rows)), 'runs')
rng = np.random.default_rng(0)
Z = rng.standard_normal((20000, 3))
def q95(C):
    l = np.clip(np.linalg.eigvalsh((C + C.T) / 2), 0, None)
    return np.sqrt(np.quantile((Z**2) @ l, 0.95))
def cover(k_loc, sm, sf):
    inside = []; bounds = []; errs = []
    for r in rows:
        L = np.array(r['located_position_covariance_m2']); n = np.array(r['normal_base'])
        C = k_loc * L + np.outer(n, n) * sm**2
        if r['face_centre']:
            C += (np.eye(3) - np.outer(n, n)) * sf**2
        b = q95(C); e = r['distance_m']
        inside.append(e <= b); bounds.append(b); errs.append(e)
    return np.mean(inside), np.median(bounds) / np.median(errs), np.median(bounds), np.median(errs)
cur = np.mean([r['distance_m'] * 1e3 <= r['predicted_error_mm'] for r in rows])
print('as run: coverage %.3f, median bound %.2f mm, median error %.2f mm' % (cur, np.median([r['predicted_error_mm'] for r in rows]), 1e3 * np.median([r['distance_m'] for r in rows])))
for run in sorted(set(r['run'] for r in rows)):
    rr = [r for r in rows if r['run'] == run]
    print('  %-22s coverage %.2f  median bound %.2f  median err %.2f  max err %.2f' % (run, np.mean([r['distance_m'] * 1e3 <= r['predicted_error_mm'] for r in rr]), np.median([r['predicted_error_mm'] for r in rr]), 1e3 * np.median([r['distance_m'] for r in rr]), 1e3 * max(r['distance_m'] for r in rr)))
for k in [0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 1.0]:
    for sm in [0.0004, 0.0006]:
        c, ratio, b, e = cover(k, sm, sm)
        print('k %.2f model %.1f mm: coverage %.3f, median bound / error %.2f (%.2f / %.2f mm)' % (k, sm * 1e3, c, ratio, b * 1e3, e * 1e3))
ax = np.mean([r['axis_error_deg'] <= r['predicted_axis_error_deg'] for r in rows])
print('axis coverage %.3f, median axis bound %.2f deg, median axis error %.2f deg' % (ax, np.median([r['predicted_axis_error_deg'] for r in rows]), np.median([r['axis_error_deg'] for r in rows])))
