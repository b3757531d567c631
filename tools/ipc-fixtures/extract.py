#!/usr/bin/env python3
"""Extracts the module<->central byte streams of the C IPC captures into
wire/tests/fixtures/ipc-central/<capture>.txt for the central replay test.

Usage: tools/ipc-fixtures/extract.py ../shared/fixtures/ipc wire/tests/fixtures/ipc-central

Output lines: `<time> <conn> <C|M> <hex>  # <label>`: conn = TCP stream number
of the module's connection to central (in connect order), C = central -> module,
M = module -> central. Module<->module direct links are left out.
"""
import re, sys, os

HDR = re.compile(r'^\[(\d+\.\d+)\] (\S+) -> (\S+)\s+(RAW|hdr:)')

def blocks(path):
    cur = None
    for line in open(path):
        m = HDR.match(line)
        if m:
            if cur: yield cur
            cur = dict(t=m.group(1), src=m.group(2), dst=m.group(3), raw=m.group(4) == 'RAW',
                       label='', bytes=None, data='', line=line)
            if cur['raw']:
                cur['bytes'] = line.split('hex')[-1].strip()
                cur['label'] = 'raw msgInfo id'
            continue
        if line.startswith('[') and cur:
            yield cur; cur = None; continue
        if cur is None: continue
        s = line.strip()
        if s.startswith('msg='): cur['label'] = s[4:].strip()
        elif s.startswith('bytes:'): cur['bytes'] = s[6:].replace(' ', '')
        elif s.startswith('data('): cur['data'] = s
    if cur: yield cur

def streams(path):
    """tshark 'follow tcp,hex' output -> {stream: {0: bytes to node1, 1: bytes from node1}}"""
    out = {}; sid = None
    for line in open(path):
        m = re.match(r'Filter: tcp.stream eq (\d+)', line)
        if m: sid = int(m.group(1)); out[sid] = {0: bytearray(), 1: bytearray()}; continue
        m = re.match(r'^(\t?)([0-9A-Fa-f]{8})  ((?:[0-9a-f]{2} {1,2})+)', line)
        if m and sid is not None:
            d = 1 if m.group(1) else 0   # tab-indented = from node 1 (central)
            out[sid][d] += bytes.fromhex(m.group(3).replace(' ', ''))
    return out

def main(src_dir, out_dir):
    os.makedirs(out_dir, exist_ok=True)
    caps = [('demo-central', 'demo-central/decoded-fullhex.txt', None),
            ('demo-direct', 'demo-direct/decoded-fullhex.txt', None),
            ('wiretest-central', 'wiretest-central/decoded-fullhex.txt', None),
            ('wiretest-direct', 'wiretest-direct/decoded-fullhex.txt', None),
            ('flowcontrol-capacity1', 'flowcontrol/decoded-cap1.txt', 'flowcontrol/flow-cap1.streams-hex.txt'),
            ('flowcontrol-capacity2', 'flowcontrol/decoded-cap2.txt', 'flowcontrol/flow-cap2.streams-hex.txt')]
    for name, dec, sh in caps:
        names = {}   # decoder name -> conn number
        nconn = 0
        st = streams(os.path.join(src_dir, sh)) if sh else None
        pos = {}
        lines = []
        for b in blocks(os.path.join(src_dir, dec)):
            if 'direct' in b['line'].split('->')[0] or b['src'] == 'direct' or b['dst'] == 'direct':
                continue
            if b['src'] == 'central': who, d = b['dst'], 'C'
            elif b['dst'] == 'central': who, d = b['src'], 'M'
            else: continue
            if who not in names:
                names[who] = nconn; nconn += 1
            conn = names[who]
            if 'x_ipc_newModuleConnectMsg' in b['label'] and d == 'M' and b['data']:
                m = re.search(r"\['([^']+)'", b['data'])
                if m: names[m.group(1)] = conn
            if st is not None:
                buf = st[conn][1 if d == 'C' else 0]
                p = pos.get((conn, d), 0)
                if b['raw']: n = 4
                else:
                    ct = int.from_bytes(buf[p:p+4], 'big'); mt = int.from_bytes(buf[p+4:p+8], 'big')
                    n = 28 + ct + mt
                hx = buf[p:p+n].hex(); pos[(conn, d)] = p + n
                if b['bytes'] and not hx.startswith(b['bytes'][:40]):
                    sys.exit(f'{name}: stream bytes disagree with the decode at {b["t"]}')
            else:
                hx = b['bytes']
            lines.append(f"{b['t']} {conn} {d} {hx}  # {b['label']}")
        with open(os.path.join(out_dir, name + '.txt'), 'w') as f:
            f.write(f'# {name}: module<->central frames of ../shared/fixtures/ipc/{dec}'
                    f'{" (bytes from " + sh + ")" if sh else ""}\n')
            f.write('# <time> <conn> <C = central->module | M = module->central> <frame hex>  # <decoder label>\n')
            f.write('\n'.join(lines) + '\n')
        print(name, len(lines), 'frames,', nconn, 'connections')

if __name__ == '__main__':
    main(sys.argv[1], sys.argv[2])
