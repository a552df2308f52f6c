{#- /api/review.js: what `photoshape gallery --serve` adds to every page it sends (export/review_server.py).
    Grades of now on every page (GET grades_url), grade buttons and keys on a PhotoShape's page (POST grade_url).
    Text from the database only ever becomes textContent, never HTML. -#}
(function(){
  const cfg={{ config | tojson }};
  const root=document.documentElement;
  const gradeClass=(g)=>(g==='good'||g==='acceptable')?g:(/^(wrong|under|over)/.test(g)?'wrong':'');
  function badge(label){const s=document.createElement('span');
    if(label){s.className=('grade '+gradeClass(label)).trim();s.textContent=label;}
    else{s.className='muted';s.textContent='ungraded';}
    return s;}
  const keyOf=(el)=>el.dataset.pair+'/'+el.dataset.methodKey;

  // index.html: each row's badge, its sort rank and the filter (gallery.js) follow the database
  function showIndex(grades){
    const table=document.getElementById('photoshapes'); if(!table) return;
    let ungraded=0;
    for(const row of table.tBodies[0].rows){const now=grades[keyOf(row)];
      if(now){row.dataset.grade=now.label||'';row.dataset.graderank=now.label?(cfg.order[now.label]??99):99;
        const cell=row.querySelector('.grade-cell'); if(cell) cell.replaceChildren(badge(now.label));}
      ungraded+=!row.dataset.grade;}
    const text=document.getElementById('text-filter'); if(text) text.dispatchEvent(new Event('input'));
    const controls=document.querySelector('.controls');
    if(controls){let note=document.getElementById('review-summary');
      if(!note){note=document.createElement('span');note.id='review-summary';note.className='review-note';controls.append(note);}
      note.textContent='review mode: '+ungraded+' of '+table.tBodies[0].rows.length+' ungraded; open one to grade it';}
  }

  // a PhotoShape's page: the grade shown, a button per grade (and its key), a note
  function showGrade(el,now){
    el.replaceChildren(badge(now.label));
    if(now.note) el.append(' \u2014 '+now.note);
    if(now.grader){const who=document.createElement('span');who.className='muted';who.textContent=' ('+now.grader+')';el.append(who);}
    el.dataset.grade=now.label||'';
    document.querySelectorAll('#review button[data-label]').forEach((b)=>b.setAttribute('aria-pressed',String(b.dataset.label===now.label)));
  }
  function panel(el){
    const box=document.createElement('section');box.id='review';box.className='review';
    const title=document.createElement('h2');title.textContent='Grade this PhotoShape';box.append(title);
    const buttons=document.createElement('div');buttons.className='review-buttons';
    for(const [key,label] of cfg.grades){const b=document.createElement('button');b.type='button';
      b.dataset.label=label;b.dataset.key=key;b.title='key '+key;
      const k=document.createElement('kbd');k.textContent=key;b.append(k,' '+label);
      b.addEventListener('click',()=>send(el,label));buttons.append(b);}
    const note=document.createElement('input');note.id='review-note-text';note.type='text';note.maxLength=2000;
    note.placeholder='note (optional), saved with the grade';
    const status=document.createElement('p');status.id='review-status';status.setAttribute('aria-live','polite');
    status.className='muted';status.textContent='Click a grade or press its key; it is written to the database at once.';
    const back=document.createElement('a');back.href='/index.html?grade=ungraded';back.textContent='the ungraded PhotoShapes';
    const nav=document.createElement('p');nav.append('Back to ',back,' (Alt+\u2190 returns to the list as you left it).');
    box.append(buttons,note,status,nav);
    el.closest('section').after(box);
    document.addEventListener('keydown',(ev)=>{
      const typing=ev.target instanceof Element&&ev.target.closest('input,textarea,select');
      if(ev.ctrlKey||ev.metaKey||ev.altKey||typing) return;
      const hit=cfg.grades.find(([key])=>key===ev.key); if(!hit||box.dataset.disabled) return;
      ev.preventDefault();send(el,hit[1]);});
  }
  async function send(el,label){
    const status=document.getElementById('review-status'),note=document.getElementById('review-note-text');
    status.className='muted';status.textContent='saving '+label+'\u2026';
    try{const r=await fetch(cfg.grade_url,{method:'POST',headers:{'Content-Type':'application/json'},
        body:JSON.stringify({pair_id:Number(el.dataset.pair),method_key:el.dataset.methodKey,
                             assignment_set:el.dataset.assignmentSet||null,label:label,note:note.value||null})});
      const body=await r.json();
      if(!r.ok){status.className='error';status.textContent='not saved: '+body.error;return;}
      showGrade(el,body);status.className='saved';
      status.textContent='saved: '+body.label+(body.note?' ('+body.note+')':'')+' by '+body.grader;
    }catch(err){status.className='error';status.textContent='not saved: '+err;}
  }
  function stale(el,now){
    const box=document.getElementById('review'); if(box) box.dataset.disabled='yes';
    document.querySelectorAll('#review button').forEach((b)=>{b.disabled=true;});
    const status=document.getElementById('review-status');
    if(status){status.className='error';status.textContent='The materials of this PhotoShape changed since these renders were '+
      'made: photoshape run publish --pair '+el.dataset.pair+' renders them again; grade it then.';}
  }

  async function start(){
    const el=document.getElementById('grade');
    if(el&&el.dataset.published) panel(el);
    try{const r=await fetch(cfg.grades_url,{cache:'no-store'});const body=await r.json();
      if(!r.ok) throw new Error(body.error);
      showIndex(body.grades);
      const now=el?body.grades[keyOf(el)]:null;
      if(now&&now.assignment_set&&el.dataset.assignmentSet&&now.assignment_set!==el.dataset.assignmentSet) stale(el,now);
      else if(now){showGrade(el,now);const note=document.getElementById('review-note-text');if(note&&now.note) note.value=now.note;}
    }catch(err){const status=document.getElementById('review-status');
      if(status){status.className='error';status.textContent='grades could not be read: '+err;}}
    root.dataset.review='ready';
  }
  start();
})();
